"""The infrastructure every domain may use: settings, the database and its models, errors,
security, request bounds and limits, logging, the schema's migrations, housekeeping."""

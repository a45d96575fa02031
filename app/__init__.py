"""app: the weldpool service (REST API, browser UI, database, job queue, CLI)."""

"""The teacher's room: its models in this process (``runtime``), the warm-up of a frame's
embedding before its first click (``warm``), its jobs (teacher and embedding runs, ``tasks``) and
its endpoints (``routes``)."""

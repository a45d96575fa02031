"""Proposals: what a model offers for a frame before a reviewer decides.

- ``files``: a proposal's mask and heatmap files and the guarded write of one frame's rows.
- ``record``: ``record_proposal``, the one way the teacher, the student and propagation store a
  proposal; it always sets the frame's status and rescores it for the queue.
- ``policy``: which source's proposal a reviewer sees, measured on reviewed frames.
- ``queue``: each frame's uncertainty from its latest proposals, and the diverse queue head.
"""

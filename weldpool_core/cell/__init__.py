"""What runs beside the robot, in the welding cell: the live student on a camera stream
(``stream``), its geometry smoothed over time (``smoothing``), the simulated pool a controller
is tried against (``plant``), and the outputs that carry each frame's figures to the cell's
controllers (``outputs``: ZeroMQ, OPC UA, MQTT)."""

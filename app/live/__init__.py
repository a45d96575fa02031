"""Live views of a student on a camera, URL or video stream (see ``app.live.service``)."""

"""moto's S3 app behind waitress, a server that keeps connections open as S3 and MinIO do
(``moto_server``'s werkzeug closes every connection after one request, so each PUT pays a new
TCP connection and a new thread on both sides). For ``bench/storage.py``.

    .venv/bin/python bench/moto_waitress.py PORT
"""

from __future__ import annotations

import os
import sys


def main() -> None:
    port = int(sys.argv[1])
    os.environ.setdefault("MOTO_PORT", str(port))
    from moto.moto_server.werkzeug_app import DomainDispatcherApplication, create_backend_app
    from waitress import serve

    serve(DomainDispatcherApplication(create_backend_app), host="127.0.0.1", port=port, threads=8)


if __name__ == "__main__":
    main()

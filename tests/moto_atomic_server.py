"""``python tests/moto_atomic_server.py HOST PORT``: moto's S3 server (the app its
``moto_server`` command runs, threaded as there), handling one request at a time.

S3 applies a conditional write (``If-Match``, ``If-None-Match``) atomically: of several
writers holding one ETag, one succeeds and the others get 412.  moto 5 checks the condition
and then writes, without a lock between the two, so under its threaded server two
concurrent conditional writes can both succeed, which S3 never does (the lease tests saw
two takers of one expired lease).  Serialising requests gives moto S3's guarantee; nothing
else about the server changes."""

from __future__ import annotations

import sys
import threading

from moto.server import DomainDispatcherApplication, create_backend_app
from werkzeug.serving import WSGIRequestHandler, run_simple

try:  # moto >= 5.2.5 serves through its own handler (headers with underscores kept)
    from moto.server import MotoRequestHandler as RequestHandler
except ImportError:  # earlier moto 5 releases run werkzeug's own, as their moto_server does
    RequestHandler = WSGIRequestHandler


class OneAtATime:
    """A WSGI application that runs ``app`` for one request at a time, its response body
    read whole inside the lock."""

    def __init__(self, app):
        self.app, self.lock = app, threading.Lock()

    def __call__(self, environ, start_response):
        with self.lock:
            result = self.app(environ, start_response)
            try:
                return [b"".join(result)]
            finally:
                if hasattr(result, "close"):
                    result.close()


def main(host: str, port: int) -> None:
    app = DomainDispatcherApplication(create_backend_app)
    run_simple(host, port, OneAtATime(app), threaded=True, request_handler=RequestHandler)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]))

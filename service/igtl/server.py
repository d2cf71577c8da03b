"""The OpenIGTLink server: one thread per peer, blocking reads, each message answered as soon as it arrives.

pyigtl's own OpenIGTLinkServer is not used: it installs SIGINT/SIGTERM handlers (which fails off the main thread
and fights uvicorn's), serves one peer at a time, and polls its queues every 10 ms.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import socketserver
import threading

from contracts.model import ModelFolder

from ..info import ModelInfo
from ..model import Predictor
from .points import OutsidePoint
from .responder import Peer, Responder
from .wire import Malformed, Refused, read_message, status

log = logging.getLogger(__name__)


class IgtlError(ValueError):
    """The OpenIGTLink settings cannot be served (a target outside the mesh, a bad target list)."""


class _Peer(socketserver.BaseRequestHandler):
    def handle(self):
        sock, server = self.request, self.server
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        server.peers.add(sock)
        log.info("OpenIGTLink peer %s:%d connected", *self.client_address[:2])
        try:
            self._serve(sock, server)
        except OSError:  # the peer went away mid-message, or stop() closed the socket
            pass
        finally:
            server.peers.discard(sock)
            log.info("OpenIGTLink peer %s:%d gone", *self.client_address[:2])

    @staticmethod
    def _serve(sock: socket.socket, server: _Server) -> None:
        peer = Peer()
        while True:
            try:
                message = read_message(sock)
                if message is None:
                    return
                data = b"".join(m.pack() for m in server.responder.answer(server.predictor, message, peer))
            except Refused as exc:
                data = status(str(exc)).pack()
            except Malformed as exc:
                sock.sendall(status(f"closing the connection: {exc}").pack())
                return
            except Exception:  # a bug must not take the server down: say so and read on
                log.exception("OpenIGTLink message failed")
                data = status("internal error; see the service log").pack()
            sock.sendall(data)


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    block_on_close = False
    peers: set


class IgtlServer:
    """The OpenIGTLink server, one thread per peer; `start` binds and serves, `stop` closes."""

    def __init__(self, responder: Responder, *, host: str, port: int):
        self.responder, self.host, self.port = responder, host, port
        self._server: _Server | None = None

    def start(self, predictor: Predictor) -> IgtlServer:
        server = _Server((self.host, self.port), _Peer)
        server.responder, server.predictor, server.peers = self.responder, predictor, set()
        self._server, self.port = server, server.server_address[1]
        threading.Thread(target=server.serve_forever, name="igtl", daemon=True).start()
        log.info("OpenIGTLink server on %s:%d", self.host, self.port)
        return self

    def stop(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            for sock in list(self._server.peers):  # peers see the connection close
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
            self._server = None


def igtl_server(settings, folder: ModelFolder, info: ModelInfo | None = None) -> IgtlServer | None:
    """The server the settings ask for (None unless settings.igtl); IgtlError if it cannot serve them."""
    if not settings.igtl:
        return None
    try:
        responder = Responder(folder, targets=settings.igtl_targets, surface=settings.igtl_surface, info=info)
    except OutsidePoint as exc:
        raise IgtlError(f"--igtl-targets: {str(exc).removeprefix('lesion ')}") from None
    return IgtlServer(responder, host=settings.host, port=settings.igtl_port)

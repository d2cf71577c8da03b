"""OpenIGTLink framing: read one message off a socket, with pyigtl's message classes; the status STRING.

pyigtl's own OpenIGTLinkServer is not used (service/igtl/server.py says why); its message classes pack and parse.
"""

from __future__ import annotations

import socket
import struct

import pyigtl
from pyigtl.messages import CRC64

from .devices import STATUS_NAME

MAX_BODY_BYTES = 1 << 20  # a TRANSFORM body is 48 bytes, a POINT 136 a point; anything near this is not a message


class Refused(ValueError):
    """One message cannot be used (bad CRC, malformed, unsupported); the stream reads on."""


class Malformed(ValueError):
    """The stream cannot be read on: the header is garbage or the body too large."""


def status(text: str):
    return pyigtl.StringMessage(text, device_name=STATUS_NAME)


def _read_exactly(sock: socket.socket, n: int) -> bytes | None:
    chunks, left = [], n
    while left:
        chunk = sock.recv(min(left, 1 << 16))
        if not chunk:
            return None
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def read_message(sock: socket.socket):
    """The next message as a pyigtl message; None at EOF.

    Raises Refused for a message that cannot be used, Malformed when the stream's framing is lost.
    """
    header = _read_exactly(sock, pyigtl.MessageBase.IGTL_HEADER_SIZE)
    if header is None:
        return None
    try:
        fields = pyigtl.MessageBase.parse_header(header)
    except (UnicodeDecodeError, struct.error) as exc:
        raise Malformed(f"unreadable OpenIGTLink header ({exc})") from None
    if fields["body_size"] > MAX_BODY_BYTES:
        raise Malformed(f"message body of {fields['body_size']} bytes (at most {MAX_BODY_BYTES})")
    body = _read_exactly(sock, fields["body_size"])
    if body is None:
        return None
    if CRC64(body) != struct.unpack(">Q", header[50:58])[0]:
        raise Refused(f"refused {fields['message_type']} {fields['device_name']!r}: CRC does not match the body")
    message = pyigtl.MessageBase.create_message(fields["message_type"])
    if message is None:
        raise Refused(f"ignored {fields['message_type']} {fields['device_name']!r}: unsupported message type")
    try:
        message.unpack(fields, body)
    except Exception as exc:  # pyigtl raises struct.error, ValueError, ... on short or odd bodies
        raise Refused(f"refused {fields['message_type']} {fields['device_name']!r}: malformed body ({exc})") from None
    return message

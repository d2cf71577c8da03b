"""`python -m service.healthcheck`: exit 0 when the service configured by the DEFORM_* environment answers /readyz.

The container's HEALTHCHECK: it reads the same settings as the service, so it follows the port and
speaks HTTPS when a certificate is set. It asks the loopback interface, so the certificate's name
(issued for the public host name) is not checked; the chain is not either, as it may be self-signed.
"""

from __future__ import annotations

import ssl
import sys
import urllib.request

from .settings import Settings


def main() -> int:
    settings = Settings()
    tls = settings.ssl_certfile is not None
    url = f"{'https' if tls else 'http'}://127.0.0.1:{settings.port}/readyz"
    context = ssl._create_unverified_context() if tls else None  # noqa: S323 - loopback, see the docstring
    try:
        with urllib.request.urlopen(url, timeout=2, context=context) as reply:
            return 0 if reply.status == 200 else 1
    except OSError as exc:
        print(f"{url}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

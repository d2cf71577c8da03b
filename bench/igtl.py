"""OpenIGTLink round trip over loopback: NeedleGuide pose out, DeformedPoints back; prints p50/p99.

    python -m bench igtl [--model models/default] [--n 2000] [--client socket|pyigtl] [--targets 4]

`socket` is a blocking client that reads the reply as soon as it arrives (as Slicer's OpenIGTLink
library does); `pyigtl` is pyigtl's client, which polls its queues every 10 ms.
"""

from __future__ import annotations

import argparse
import socket
import time

import numpy as np
import pyigtl

from service.guide import Guide
from service.igtl import POINTS_NAME, IgtlServer, Responder, read_message
from service.model import Predictor, read_model_folder
from service.settings import DEFAULT_MODEL

from bench._report import Report
from studies import results


def socket_round_trips(port: int, poses: list[np.ndarray]) -> np.ndarray:
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        seconds = []
        for pose in poses:
            data = pyigtl.TransformMessage(pose, device_name="NeedleGuide").pack()
            t0 = time.perf_counter()
            sock.sendall(data)
            reply = read_message(sock)
            seconds.append(time.perf_counter() - t0)
            assert reply.device_name == POINTS_NAME, reply
    return np.array(seconds)


def pyigtl_round_trips(port: int, poses: list[np.ndarray]) -> np.ndarray:
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
    seconds = []
    for pose in poses:
        t0 = time.perf_counter()
        client.send_message(pyigtl.TransformMessage(pose, device_name="NeedleGuide"), wait=True)
        reply = client.wait_for_message(POINTS_NAME, timeout=10)
        seconds.append(time.perf_counter() - t0)
        assert reply is not None
    client.stop()
    return np.array(seconds)


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m bench igtl", description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=DEFAULT_MODEL)
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--client", choices=("socket", "pyigtl"), default="socket")
    ap.add_argument("--targets", type=int, default=4, help="target points inside the prostate, sent with the markers")
    results.add_publish_flag(ap)
    args = ap.parse_args(argv)
    say = Report()
    folder = read_model_folder(args.model)
    prostate = folder.mesh.tissue == folder.manifest.mesh.tissues.index("prostate")
    targets = {f"target_{i}": folder.nodes[t[:4]].mean(0).tolist()
               for i, t in enumerate(folder.tets[prostate][:args.targets])}
    server = IgtlServer(Responder(folder, targets=targets), host="127.0.0.1", port=0).start(Predictor(folder))
    guide = Guide.of(folder.manifest)
    poses = [guide.pose(d, b) for d, b in folder.manifest.envelope.sample(args.n, seed=0)]
    run = socket_round_trips if args.client == "socket" else pyigtl_round_trips
    run(server.port, poses[:20])  # warm-up
    ms = 1e3 * run(server.port, poses)
    server.stop()
    say(f"{folder.manifest.name}: {args.n} poses, {len(targets) + len(folder.regions['markers'])} points each, "
          f"{args.client} client: p50 {np.percentile(ms, 50):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, "
          f"max {ms.max():.3f} ms")
    print(f"wrote {results.write('bench_igtl', {'lines': say.lines}, publish=args.publish)}")
    return 0

"""CPU time of the live twin's views per second of live data: two nodes at 80 Hz, 20 sends a
second, a forecast (3 s ahead at 12.5 ms) and a parameter check each second (the twin's budget is
20 % of one core in all). Data are made up and fed as fast as the views take them; CPU time is the
process's (the Foxglove server's own threads included).

- Rerun: to an .rrd file (the viewer's work is the viewer's process);
- Foxglove: no client (nothing encoded), and one client subscribed to every channel and reading
  (a thread here with the ``websockets`` client, its own CPU time included: an upper bound).

Run: python bench/bench_twin_views.py [--seconds 30]
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from pendsim_bridge.report.twin_foxglove import TwinFoxgloveView
from pendsim_bridge.report.twin_rerun import TwinRerunView
from pendsim_mj.rig.model import exact_mjcf
from pendsim_mj.twin.estimator import Forecast
from pendsim_mj.twin.outputs import Estimates, ParameterCheck

NODES = ("m1", "m2")
RATE_HZ, SENDS_HZ = 80.0, 20.0


def batches(seconds: float) -> list[tuple[Estimates, Forecast | None, ParameterCheck | None]]:
    """Per send: the estimates of 50 ms (both nodes), and on whole seconds a forecast and a check."""
    rng = np.random.default_rng(0)
    out = []
    per = round(RATE_HZ / SENDS_HZ)
    for b in range(round(seconds * SENDS_HZ)):
        t = np.repeat(b / SENDS_HZ + np.arange(per) / RATE_HZ, 2) + np.tile([0.0, 0.5 / RATE_HZ], per)
        n = len(t)
        node = np.tile([0, 1], per).astype(np.int64)
        state = np.stack([0.3 * np.cos(5.6 * t), 0.2 * np.cos(5.6 * t), -1.7 * np.sin(5.6 * t), np.sin(5.6 * t)], 1)
        est = Estimates(t, node, rng.normal(size=(n, 2)), state, np.full((n, 4), 0.01), rng.normal(size=(n, 2)),
                        np.full((n, 2), 0.01), rng.random(n), rng.normal(size=(n, 2)), rng.normal(size=(n, 2)),
                        np.full((n, 2), 0.011), rng.random(n))  # fmt: skip
        forecast = check = None
        if b % round(SENDS_HZ) == 0:
            ft = t[0] + np.arange(241) * 0.0125
            forecast = Forecast(ft, np.zeros((241, 4)) + 0.1, np.full((241, 4), 0.01))
            check = ParameterCheck(float(t[0]), ("b1_n_m_s", "coupling_sin_n_m"), np.array([1e-4, 0.05]),
                                   np.array([1e-6, 1e-3]), np.array([1e-4, 0.05]), np.zeros(2))  # fmt: skip
        out.append((est, forecast, check))
    return out


def feed(view, data) -> float:
    """CPU seconds to feed and close the view."""
    start = time.process_time()
    for est, forecast, check in data:
        view.add_estimates(est)
        if forecast is not None:
            view.add_forecast(float(est.t_s[0]), forecast)
        if check is not None:
            view.add_parameters(check)
        view.send()
    view.close()
    return time.process_time() - start


@dataclasses.dataclass
class Client:
    """A Foxglove WebSocket client on its own thread, subscribed to everything, counting frames."""

    port: int
    frames: int = 0
    ready: threading.Event = dataclasses.field(default_factory=threading.Event)

    def run(self) -> None:
        from websockets.asyncio.client import connect
        from websockets.exceptions import ConnectionClosed

        async def session() -> None:
            async with connect(f"ws://127.0.0.1:{self.port}", subprotocols=["foxglove.sdk.v1"]) as ws:
                await ws.recv()
                channels = json.loads(await ws.recv())["channels"]
                subs = [{"id": k, "channelId": c["id"]} for k, c in enumerate(channels)]
                await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                self.ready.set()
                try:
                    while True:
                        await ws.recv()
                        self.frames += 1
                except ConnectionClosed:
                    pass

        asyncio.run(session())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    data = batches(args.seconds)
    mjcf = exact_mjcf()
    rows = sum(len(d[0]) for d in data)
    print(f"{args.seconds:g} s of live data: {rows} samples, {len(data)} sends")
    with tempfile.TemporaryDirectory() as tmp:
        cpu = feed(TwinRerunView(1_780_000_000_000_000_000, NODES, mjcf, rrd=Path(tmp) / "twin.rrd"), data)
        size = (Path(tmp) / "twin.rrd").stat().st_size / 1e6
    print(f"Rerun (.rrd):             {1e3 * cpu / args.seconds:6.1f} ms CPU per s of data "
          f"({100 * cpu / args.seconds:.1f} % of a core), {size:.1f} MB")  # fmt: skip
    cpu = feed(TwinFoxgloveView(1_780_000_000_000_000_000, NODES, mjcf_xml=mjcf, port=0), data)
    print(f"Foxglove, no client:      {1e3 * cpu / args.seconds:6.1f} ms CPU per s of data "
          f"({100 * cpu / args.seconds:.1f} % of a core)")  # fmt: skip
    view = TwinFoxgloveView(1_780_000_000_000_000_000, NODES, mjcf_xml=mjcf, port=0)
    client = Client(view.port)
    thread = threading.Thread(target=client.run)
    thread.start()
    client.ready.wait(10)
    while not all(c.has_sinks() for c in view.channels.values()):
        time.sleep(0.01)
    cpu = feed(view, data)
    thread.join(10)
    print(f"Foxglove, 1 client (all): {1e3 * cpu / args.seconds:6.1f} ms CPU per s of data "
          f"({100 * cpu / args.seconds:.1f} % of a core with the client), {client.frames} frames")  # fmt: skip


if __name__ == "__main__":
    main()

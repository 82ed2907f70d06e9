"""Does a graph run faster under other onnxruntime session options? One graph, one session per
option set, timed in blocks of calls that rotate between the sessions (a pause between blocks,
so that one session's threads are quiet before the next one's block): the median and 90th
percentile of a call, and the process CPU time a call costs (spinning threads cost CPU).

    python -m benchmarks.session_options itnet/models/classifier.onnx
    python -m benchmarks.session_options itnet/models/chair.onnx --points 1024

Option sets: the service's (``service/runtime.py`` ``session_options``: 2 threads, no
spinning), one thread, 2 threads spinning, and 2 threads spinning only during a run
(``session.force_spinning_stop``). Inputs: random clouds ``[1, points, 3]``, and an identity
``pose`` where the graph takes one (a pose step).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

from itnet.pose.runtime import session_options

OPTIONS = {
    "served (2 threads, no spinning)": {"threads": 2},
    "1 thread": {"threads": 1},
    "2 threads, spinning": {"threads": 2, "spinning": True},
    "2 threads, spinning during a run": {"threads": 2, "spinning": True, "stop": True},
}


def options(threads: int, spinning: bool = False, stop: bool = False) -> ort.SessionOptions:
    made = session_options(threads, spinning)
    if stop:
        made.add_session_config_entry("session.force_spinning_stop", "1")
    return made


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", type=Path)
    parser.add_argument("--points", type=int, default=256)
    parser.add_argument("--blocks", type=int, default=8, help="blocks of calls per option set")
    parser.add_argument("--calls", type=int, default=100, help="calls per block")
    args = parser.parse_args()

    sessions = {
        name: ort.InferenceSession(
            str(args.model), options(**kw), providers=["CPUExecutionProvider"]
        )
        for name, kw in OPTIONS.items()
    }
    inputs = [i.name for i in next(iter(sessions.values())).get_inputs()]
    rng = np.random.default_rng(0)
    feeds = []
    for _ in range(8):
        feed = {inputs[0]: rng.normal(size=(1, args.points, 3)).astype(np.float32)}
        if "pose" in inputs:
            feed["pose"] = np.eye(4, dtype=np.float32)[None]
        feeds.append(feed)
    for session in sessions.values():  # warm up
        for feed in feeds:
            session.run(None, feed)
    times: dict[str, list[float]] = {name: [] for name in sessions}
    cpu: dict[str, list[float]] = {name: [] for name in sessions}
    for block in range(args.blocks):
        order = list(sessions) if block % 2 else list(reversed(list(sessions)))
        for name in order:
            time.sleep(0.05)
            start_cpu = time.process_time()
            for i in range(args.calls):
                start = time.perf_counter()
                sessions[name].run(None, feeds[i % len(feeds)])
                times[name].append(1e3 * (time.perf_counter() - start))
            cpu[name].append(1e3 * (time.process_time() - start_cpu) / args.calls)
    result = {
        "model": str(args.model),
        "points": args.points,
        "calls": args.blocks * args.calls,
        "machine": f"{platform.machine()} {os.cpu_count()} cores",
        "options": {
            name: {
                "median_ms": round(float(np.median(times[name])), 2),
                "p90_ms": round(float(np.percentile(times[name], 90)), 2),
                "cpu_ms_per_call": round(float(np.mean(cpu[name])), 2),
            }
            for name in sessions
        },
    }
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""The peer: a JetBot-style Python loop against jetpilot's, interleaved in one run.

Per frame, the Python loop does what JetBot's road-following live demo does with a camera
frame: PIL resize of the 640x480 RGB array to the model's input size, numpy normalisation
with the model's mean/std (ImageNet), `onnxruntime.InferenceSession.run`, then JetBot's
steering law (`angle = atan2(x, (0.5 - y) / 2)`, PD, `left/right = clamp(speed_gain +-
steering, 0, 1)`) and JetBot's motor value mapping (no I2C bus here; jetpilot encodes its
PCA9685 writes to a null bus, which costs about 0.2 us).

jetpilot's side is `jetpilot bench --model FILE --peer DIR` (src/cli/bench_peer.rs): it
writes `bench`'s synthetic 640x480 frames to DIR, and for each frame count sent on its
standard input times that many frames of the daemon's per-frame path and answers with the
times. Both stay loaded for the whole run; the script alternates blocks of its own loop
with blocks of jetpilot's (the order flipping every round, a short pause before each block
so the other session's threads stop spinning), on the same model file and the same frames,
so the machine's load falls on both alike. It prints both medians and their ratio.

ONNX Runtime is the same version as jetpilot's library (1.23.2), from PyPI, in a venv under
.cache/peer-venv that the script makes (once) and re-runs itself in:

    cargo build --release
    python3 benches/peer_python_loop.py                        # random ResNet-18s, 224 and 112
    python3 benches/peer_python_loop.py --model path/to/model.onnx

Not part of the test suite.
"""

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REQUIREMENTS = ["onnxruntime==1.23.2", "numpy==2.4.6", "pillow==13.0.0"]
ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".cache" / "peer-venv"
STAMP = VENV / "jetpilot-requirements.txt"

# JetBot live demo sliders (steering gain 0.2 default, kd and bias 0); speed 0.3 as
# `jetpilot bench`, so that both motors get a value.
SPEED_GAIN, STEERING_GAIN, STEERING_KD, STEERING_BIAS = 0.3, 0.2, 0.0, 0.0


def ensure_venv():
    """Re-runs this script in .cache/peer-venv, making or updating it first if needed."""
    if Path(sys.prefix).resolve() == VENV.resolve():
        return
    wanted = "\n".join(REQUIREMENTS) + "\n"
    python = VENV / "bin" / "python"
    if not (python.exists() and STAMP.exists() and STAMP.read_text() == wanted):
        print(f"peer: installing {' '.join(REQUIREMENTS)} into {VENV}", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", "--clear", str(VENV)], check=True)
        subprocess.run(
            [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *REQUIREMENTS],
            check=True,
        )
        STAMP.write_text(wanted)
    os.execv(str(python), [str(python), str(Path(__file__).resolve()), *sys.argv[1:]])


def default_jetpilot():
    target = os.environ.get("CARGO_TARGET_DIR")
    base = Path(target) if target else ROOT / "target"
    return str(base / "release" / "jetpilot")


def load_average():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


class PythonLoop:
    """JetBot's per-frame work, in Python."""

    def __init__(self, model, ready, threads, spinning):
        import numpy as np
        import onnxruntime as ort
        from PIL import Image

        self.np, self.Image = np, Image
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        if not spinning:
            so.add_session_config_entry("session.intra_op.allow_spinning", "0")
            so.add_session_config_entry("session.inter_op.allow_spinning", "0")
        self.session = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name
        self.size = ready["input_size"]
        self.bgr = ready["channel_order"] == "bgr"
        self.mean = np.array(ready["mean"], dtype=np.float32)
        self.std = np.array(ready["std"], dtype=np.float32)
        self.angle_last = 0.0
        self.last_outputs = None

    def step(self, frame):
        """One frame; returns (total seconds, seconds in session.run)."""
        np = self.np
        t0 = time.perf_counter()
        image = self.Image.fromarray(frame)  # the camera's HxWx3 uint8 array
        image = image.resize((self.size, self.size), self.Image.BILINEAR)
        x = np.asarray(image, dtype=np.float32) / 255.0
        if self.bgr:
            x = x[:, :, ::-1]
        x = (x - self.mean) / self.std  # mean[c] on tensor plane c, as torchvision's Normalize
        x = np.ascontiguousarray(x.transpose(2, 0, 1))[None]  # [1, 3, S, S]
        t1 = time.perf_counter()
        out = self.session.run(None, {self.input_name: x})[0]
        t2 = time.perf_counter()
        self.last_outputs = (float(out[0][0]), float(out[0][1]))
        self.drive(*self.last_outputs)
        return time.perf_counter() - t0, t2 - t1

    def drive(self, x, y_raw):
        y = (0.5 - y_raw) / 2.0
        angle = math.atan2(x, y)
        pid = angle * STEERING_GAIN + (angle - self.angle_last) * STEERING_KD
        self.angle_last = angle
        steering = pid + STEERING_BIAS
        left = max(min(SPEED_GAIN + steering, 1.0), 0.0)
        right = max(min(SPEED_GAIN - steering, 1.0), 0.0)
        # jetbot.Motor._write_value: mapped = int(255 * (alpha * value + beta)), alpha 1, beta 0
        return [min(max(abs(int(255.0 * v)), 0), 255) * 16 for v in (left, right)]


class JetpilotLoop:
    """`jetpilot bench --model FILE --peer DIR`, driven over its standard input."""

    def __init__(self, jetpilot, model, threads, frames_dir):
        cmd = [jetpilot, "-q", "bench", "--model", model, "--threads", str(threads), "--peer", frames_dir]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.ready = self._read()
        if not self.ready.get("ready"):
            raise SystemExit(f"peer: unexpected first line from jetpilot: {self.ready}")

    def _read(self):
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"peer: jetpilot ended (exit {self.proc.wait()}); its errors are above")
        return json.loads(line)

    def block(self, n):
        self.proc.stdin.write(f"{n}\n")
        self.proc.stdin.flush()
        reply = self._read()
        return [t / 1e3 for t in reply["e2e_ms"]], [t / 1e3 for t in reply["infer_ms"]]

    def close(self):
        self.proc.stdin.write("0\n")
        self.proc.stdin.close()
        self.proc.wait()


def compare(args, model):
    """One interleaved comparison on `model`; returns its summary."""
    with tempfile.TemporaryDirectory(prefix="jetpilot-peer-") as frames_dir:
        jp = JetpilotLoop(args.jetpilot, model, args.threads, frames_dir)
        ready = jp.ready
        if ready["output"] != "xy":
            raise SystemExit(f"peer: {model} has a `{ready['output']}` head; JetBot's law needs `xy`")
        import numpy as np

        h, w = ready["height"], ready["width"]
        frames = [np.fromfile(p, dtype=np.uint8).reshape(h, w, 3) for p in ready["frames"]]
        py = PythonLoop(model, ready, args.threads, args.python_spinning == "on")
        i = 0

        def python_block(n):
            nonlocal i
            totals, runs = [], []
            for k in range(n + 1):  # the first frame of a block is untimed, as jetpilot's
                total, run = py.step(frames[i % len(frames)])
                i += 1
                if k > 0:
                    totals.append(total)
                    runs.append(run)
            return totals, runs

        load_start = load_average()
        python_block(args.warmup)
        jp.block(args.warmup)
        samples = {"python": ([], []), "jetpilot": ([], [])}
        block_ratios = []
        for r in range(args.rounds):
            medians = {}
            for name in (("python", "jetpilot") if r % 2 == 0 else ("jetpilot", "python")):
                time.sleep(args.pause_ms / 1e3)
                totals, runs = python_block(args.block) if name == "python" else jp.block(args.block)
                samples[name][0].extend(totals)
                samples[name][1].extend(runs)
                medians[name] = statistics.median(totals)
            block_ratios.append(medians["python"] / medians["jetpilot"])
        jp.close()
        load_end = load_average()

    def summary(name):
        totals, runs = samples[name]
        return {
            "frames": len(totals),
            "median_ms": 1e3 * statistics.median(totals),
            "run_median_ms": 1e3 * statistics.median(runs),
            "outside_run_median_ms": 1e3 * statistics.median(t - r for t, r in zip(totals, runs)),
        }

    p, j = summary("python"), summary("jetpilot")
    return {
        "model": model,
        "input_size": ready["input_size"],
        "onnxruntime_python": __import__("onnxruntime").__version__,
        "onnxruntime_jetpilot": ready["onnxruntime"],
        "threads": args.threads,
        "spinning_python": args.python_spinning,
        "spinning_jetpilot": "on" if ready["spinning"] else "off",
        "block": args.block,
        "rounds": args.rounds,
        "python": p,
        "jetpilot": j,
        "ratio_of_medians": p["median_ms"] / j["median_ms"],
        "ratio_paired_median": statistics.median(block_ratios),
        "load_average_start": load_start,
        "load_average_end": load_end,
    }


def report(s):
    size = s["input_size"]
    print(f"\n{s['model']} ({size}x{size}), onnxruntime {s['onnxruntime_python']} (Python) / "
          f"{s['onnxruntime_jetpilot']} (jetpilot), {s['threads']} intra-op threads, spinning: "
          f"Python {s['spinning_python']}, jetpilot {s['spinning_jetpilot']}")
    print(f"  {s['rounds']} rounds of {s['block']} frames each, interleaved; "
          f"load average {s['load_average_start']} -> {s['load_average_end']}")
    print(f"  {'ms per frame':<36} {'median':>9} {'run':>9} {'outside run':>12}")
    for name, label in (("python", "JetBot-style Python loop"), ("jetpilot", "jetpilot frame -> command")):
        r = s[name]
        print(f"  {label:<36} {r['median_ms']:>9.3f} {r['run_median_ms']:>9.3f} {r['outside_run_median_ms']:>12.3f}")
    print(f"  Python / jetpilot: {s['ratio_of_medians']:.3f} (ratio of medians), "
          f"{s['ratio_paired_median']:.3f} (median of per-round ratios)")


def main():
    ensure_venv()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", action="append", help="an .onnx model (repeatable); default: random ResNet-18s")
    ap.add_argument("--sizes", default="224,112", help="input sizes of the random models (without --model)")
    ap.add_argument("--jetpilot", default=default_jetpilot(), help="the jetpilot binary (default: the release build)")
    ap.add_argument("--threads", type=int, default=2, help="intra-op threads on both sides (jetpilot bench's default)")
    ap.add_argument("--python-spinning", choices=["on", "off"], default="on",
                    help="ONNX Runtime spinning in the Python session (on: its default, what a JetBot notebook gets)")
    ap.add_argument("--block", type=int, default=20, help="frames per block")
    ap.add_argument("--rounds", type=int, default=15, help="blocks of each loop")
    ap.add_argument("--warmup", type=int, default=30, help="untimed frames of each loop first")
    ap.add_argument("--pause-ms", type=float, default=100.0, help="pause before each block")
    ap.add_argument("--json", help="also write the summaries to this file")
    args = ap.parse_args()
    if not Path(args.jetpilot).exists():
        raise SystemExit(f"peer: no jetpilot at {args.jetpilot}: cargo build --release, or --jetpilot PATH")

    models = args.model
    if not models:
        out = ROOT / ".cache" / "peer"
        out.mkdir(parents=True, exist_ok=True)
        models = []
        for size in (int(s) for s in args.sizes.split(",")):
            path = out / f"resnet18-{size}.onnx"
            if not path.exists():
                subprocess.run([args.jetpilot, "-q", "model", "init", "--input-size", str(size),
                                "--seed", "0", "-o", str(path)], check=True)
            models.append(str(path))
    summaries = []
    for model in models:
        s = compare(args, model)
        report(s)
        summaries.append(s)
    if args.json:
        Path(args.json).write_text(json.dumps(summaries, indent=2) + "\n")
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()

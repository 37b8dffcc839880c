"""Run the README's commands in a fresh folder and write what they printed and wrote, hashed.

The restructuring check of issue 21: run it before and after a change that must not change
behaviour, then compare the two manifests. Wall times and other run-dependent text are masked in
the printed output; files are compared byte for byte, and a file that differs between two runs of
the same tree (``--twice``) is marked non-deterministic rather than compared.

    python bench/readme_commands.py run OUT_DIR [--twice]
    python bench/readme_commands.py compare BEFORE/manifest.json AFTER/manifest.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

#: The README's commands, in its order, that run without a rig or a viewer window (acquire/nodes
#: listen on sockets in real time and are covered by the suite's end-to-end tests).
COMMANDS: tuple[str, ...] = (
    "pendsim info",
    "pendsim demo",
    "pendsim simulate --phi1-deg 30 --duration-s 60",
    "pendsim record -o run.mcap",
    "pendsim validate run.mcap",
    "pendsim identify run.mcap",
    "pendsim view run.mcap",
    "pendsim inspect run.mcap",
    "pendsim replay run.mcap --start 6 -o cut.mcap",
    "pendsim validate cut.mcap",
    "pendsim record -o real.mcap --heading-deg 60 --mount-misalignment-deg 10 --axis-remap 0x21,0x04"
    " --packet-loss 0.05 --clock-drift-ppm 50",
    "pendsim validate real.mcap --release-s 0.0",
    "pendsim simulate --torque1-n-m sine:0.003,0.87",
    "pendsim analyze backbone",
    "pendsim analyze tongues",
    "pendsim sweep --sensitivity --features frequency -o sensitivity",
    "pendsim sweep --vary c1_n_m=4:8:3 --vary phi1_deg=10:60:3 -o c1-release",
    "pendsim record --static -o static.mcap --duration-s 60",
    "pendsim allan static.mcap",
)

_MASKS = (
    (re.compile(r"\d+(\.\d+)? ?(s|ms) (wall|CPU)"), "<time>"),
    (re.compile(r"in \d+(\.\d+)? ?s\b"), "in <time>"),
    (re.compile(r"iterations, \d+(\.\d+)? s\)"), "iterations, <time>)"),
    (re.compile(r"\d+(\.\d+)?(it/s|s/it)"), "<rate>"),
    (re.compile(r"\[\d\d:\d\d<\d\d:\d\d[^\]]*\]"), "[<eta>]"),
    # when the run was made: UTC instants, log times, and sizes of files compressed with them
    (re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z"), "<utc>"),
    (re.compile(r"log time \d+\.\d+ to \d+\.\d+ s"), "log time <t0> to <t1> s"),
    (re.compile(r"start_time_ns = \d+"), "start_time_ns = <t0>"),
    (re.compile(r"\d+\.\d+ MB"), "<size> MB"),
)


def _mask(text: str) -> str:
    for pattern, replacement in _MASKS:
        text = pattern.sub(replacement, text)
    return text


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _without_wall_times(value: object) -> object:
    if isinstance(value, dict):
        return {k: _without_wall_times(v) for k, v in value.items() if k != "seconds"}
    if isinstance(value, list):
        return [_without_wall_times(v) for v in value]
    return value


def _relative_stamps(value: object, t0_ns: int) -> object:
    """A decoded ROS 2 message as plain data, every header stamp counted from t0_ns."""
    if isinstance(value, (list, tuple)):
        return [_relative_stamps(v, t0_ns) for v in value]
    if hasattr(value, "__slots__"):
        fields = {name: getattr(value, name) for name in value.__slots__}
        if set(fields) == {"sec", "nanosec"}:
            return int(fields["sec"]) * 1_000_000_000 + int(fields["nanosec"]) - t0_ns
        return {name: _relative_stamps(v, t0_ns) for name, v in fields.items()}
    if isinstance(value, bytes):
        return value.hex()
    return value


def _normalized(path: Path) -> str:
    """A digest of what a file means, without what depends on when it was made: a JSON report
    without its ``seconds`` (wall time); an MCAP file as its decoded messages with log and publish
    times and header stamps counted from the first message's log time."""
    digest = hashlib.sha256()
    if path.suffix == ".json":
        digest.update(json.dumps(_without_wall_times(json.loads(path.read_text())), sort_keys=True).encode())
    elif path.suffix == ".mcap":
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        with open(path, "rb") as f:
            t0 = None
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
                t0 = message.log_time if t0 is None else t0
                row = (channel.topic, message.log_time - t0, message.publish_time - t0, _relative_stamps(decoded, t0))
                digest.update(repr(row).encode())
    else:
        return _sha(path)
    return digest.hexdigest()


def _run_once(folder: Path) -> dict[str, object]:
    folder.mkdir(parents=True, exist_ok=False)
    env = dict(os.environ, PYTHONHASHSEED="0", TQDM_DISABLE="1")
    runs = []
    for command in COMMANDS:
        argv = [sys.executable, "-m", "pendsim_bridge.cli", *command.split()[1:]]
        done = subprocess.run(argv, cwd=folder, env=env, capture_output=True, text=True, check=False)
        runs.append({"command": command, "rc": done.returncode, "stdout": _mask(done.stdout)})
        print(f"{done.returncode:3d}  {command}", flush=True)
    paths = [p for p in sorted(folder.rglob("*")) if p.is_file()]
    files = {str(p.relative_to(folder)): _sha(p) for p in paths}
    normalized = {str(p.relative_to(folder)): _normalized(p) for p in paths if p.suffix in (".json", ".mcap")}
    return {"runs": runs, "files": files, "normalized": normalized}


def run(out: Path, twice: bool) -> None:
    first = _run_once(out / "a")
    manifest = {**first, "nondeterministic": [], "unnormalizable": []}
    if twice:
        second = _run_once(out / "b")
        files_a, files_b = first["files"], second["files"]
        norm_a, norm_b = first["normalized"], second["normalized"]
        assert isinstance(files_a, dict) and isinstance(files_b, dict)
        assert isinstance(norm_a, dict) and isinstance(norm_b, dict)
        manifest["nondeterministic"] = sorted(k for k in files_a if files_b.get(k) != files_a[k])
        manifest["unnormalizable"] = sorted(
            k for k in manifest["nondeterministic"] if norm_b.get(k, "") != norm_a.get(k)
        )
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))


def compare(before_path: Path, after_path: Path) -> int:
    before = json.loads(before_path.read_text())
    after = json.loads(after_path.read_text())
    problems = []
    for b, a in zip(before["runs"], after["runs"], strict=True):
        if b["rc"] != a["rc"] or b["stdout"] != a["stdout"]:
            problems.append(f"output of `{b['command']}` differs (rc {b['rc']} -> {a['rc']})")
    varies = set(before["nondeterministic"])
    skip = set(before["unnormalizable"])
    for name in sorted(set(before["files"]) | set(after["files"])):
        if name in skip:
            continue
        table = "normalized" if name in varies else "files"
        if before[table].get(name) != after[table].get(name):
            problems.append(f"file {name} differs" + (" (normalized)" if name in varies else ""))
    for line in problems:
        print(line)
    compared = len(set(before["files"]) - varies)
    counts = (
        f"{len(before['runs'])} commands, {compared} files compared byte for byte, "
        f"{len(varies - skip)} by their normalized content, {len(skip)} not compared"
    )
    print(f"{counts}; {len(problems)} differences")
    return 1 if problems else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="verb", required=True)
    p_run = sub.add_parser("run")
    p_run.add_argument("out", type=Path)
    p_run.add_argument("--twice", action="store_true", help="run twice to find non-deterministic files")
    p_cmp = sub.add_parser("compare")
    p_cmp.add_argument("before", type=Path)
    p_cmp.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.verb == "run":
        run(args.out, args.twice)
    else:
        raise SystemExit(compare(args.before, args.after))


if __name__ == "__main__":
    main()

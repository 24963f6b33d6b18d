"""Real third-party log files through every command: is each message accounted for, is every error clear?

The files were written by real receivers, autopilots and instruments, not by this project: the
small ones are kept under ``tests/data/<repository>/`` (each folder's SOURCE.md gives the
repository, path, commit and licence), the larger ones (``REMOTE`` below) are taken from a local
git mirror of their repository when there is one (``--mirror``, default ``/work/.mirror``), else
downloaded from raw.githubusercontent.com at the pinned commit, else skipped with a note.

For every file the table gives:

- the format found by content sniffing, and the messages in the file as the format's own library
  counts them (pyubx2 ``UBXReader`` over UBX and RTCM streams (NMEA inside them included),
  pyulog ``ULog`` samples, pymavlink ``DFReader`` / ``mavlink_connection``, rosbags ``AnyReader``);
  for NMEA files, the sentences pynmeagps finds (those it rejects for a bad checksum, a malformed
  field or a missing line end included) plus the lines whose header pynmeagps does not take at
  all (AIS ``!AIVDM``, ``$QZ``, numeric talkers);
- what ``read_log`` read and skipped (sums of the summary; for text formats the skipped count
  also holds lines that are not messages: garbage lines, bad checksums);
- what ``vesselid ingest``, ``align``, ``segment`` and ``fit --vessel vessel_configs/aauship.toml``
  did (``segment`` with the same vessel as ``fit``): ``ok`` (with the segments), or the first line
  of the error, and the wall and CPU time of ``fit``, which runs in its own process (and process
  group, and temporary folder) with a 300 s wall-time limit when ``segment`` succeeded (else it
  stops where the earlier command stopped, and runs in this process: no CPU time given).

Checks (exit status 1 when one fails): no command lets a Python exception or traceback reach the
user (an uncaught exception, a traceback, or an exception class name such as ``ValueError`` anywhere
in what a command writes to stderr), every
error names what was expected and what was found (contains ``expected`` and ``found``), and
``fit`` ends within 300 s.

Usage::

    CI=1 .venv/bin/python benchmarks/real_files.py [--mirror DIR] [--only SUBSTRING] [--markdown]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pipeline.cli import main as cli_main  # noqa: E402
from pipeline.errors import VesselidError  # noqa: E402
from pipeline.ingest import read_log  # noqa: E402
from pipeline.ingest.sniff import sniff  # noqa: E402

DATA = ROOT / "tests" / "data"
VESSEL = ROOT / "vessel_configs" / "aauship.toml"
FIT_LIMIT_S = 300.0
#: Files too large to keep in the repository: (repository, commit, path, licence).
REMOTE = [
    ("PX4/pyulog", "3cf17793f14709713ab297d3743314c658874068", "test/sample.ulg", "BSD-3-Clause"),
    ("PX4/pyulog", "3cf17793f14709713ab297d3743314c658874068", "test/sample_log_small.ulg", "BSD-3-Clause"),
    ("PX4/pyulog", "3cf17793f14709713ab297d3743314c658874068", "test/sample_logging_tagged_and_default_params.ulg",
     "BSD-3-Clause"),
    ("PX4/pyulog", "3cf17793f14709713ab297d3743314c658874068", "test/sample_px4_events.ulg", "BSD-3-Clause"),
    ("SignalK/signalk-server", "9edfbf958eb7addb69140a605b4d21a0df249fdc", "samples/plaka.log", "Apache-2.0"),
    ("SignalK/signalk-server", "9edfbf958eb7addb69140a605b4d21a0df249fdc", "samples/gps.log", "Apache-2.0"),
    ("ntpsec/gpsd", "46977faa8f94eb036ca68c24a3fc0d233732e707", "test/daemon/ublox-zed-f9p_hpg1.11.log",
     "BSD-2-Clause"),
    ("ntpsec/gpsd", "46977faa8f94eb036ca68c24a3fc0d233732e707", "test/daemon/ublox-glo.log", "BSD-2-Clause"),
    ("ntpsec/gpsd", "46977faa8f94eb036ca68c24a3fc0d233732e707", "test/daemon/quectel-l76k-nmea.log", "BSD-2-Clause"),
]
#: Summary keys that count bytes or lines that hold no message (bad checksums and incomplete
#: sentences are messages: the libraries find them too).
_NOT_MESSAGES = ("garbage",)
#: A Python exception's class name anywhere in an error line (``ValueError``, ``AnyReaderError``...).
_EXC_NAME = re.compile(r"\b[A-Z][A-Za-z]*(Error|Exception)\b")


def fetch_remote(repo: str, commit: str, path: str, mirror: Path, cache: Path) -> Path | None:
    """The file from a local mirror (``git show``) or a download; None when neither works."""
    out = cache / repo.replace("/", "+") / Path(path).name
    if out.is_file() and out.stat().st_size:
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    git_dir = mirror / repo.replace("/", "+") / "repo"
    if git_dir.is_dir():
        res = subprocess.run(["git", f"--git-dir={git_dir}", "show", f"{commit}:{path}"], capture_output=True)
        if res.returncode != 0:
            res = subprocess.run(["git", f"--git-dir={git_dir}", "show", f"HEAD:{path}"], capture_output=True)
        if res.returncode == 0 and res.stdout:
            out.write_bytes(res.stdout)
            return out
    url = f"https://raw.githubusercontent.com/{repo}/{commit}/{path}"
    try:
        with urllib.request.urlopen(url, timeout=20) as r:
            out.write_bytes(r.read())
        return out
    except OSError:
        return None


def nmea_library_count(path: Path) -> tuple[str, int]:
    """Sentences in an NMEA file as pynmeagps counts them, and those outside its definition.

    pynmeagps' ``NMEAReader`` finds a sentence at every ``$`` followed by a talker letter it knows
    (``pynmeagps.NMEA_HDR``); a sentence it finds but cannot take (bad checksum, a field of the
    wrong type, an unterminated last line) is reported to its error handler and counted here too:
    it is still a sentence of the file. Lines that start with a header pynmeagps does not take at
    all (AIS ``!AIVDM``, the QZSS talker ``$QZ``, numeric talkers ``$02``) are counted apart.
    """
    from pynmeagps import NMEAReader
    from pynmeagps.nmeatypes_core import NMEA_HDR

    parsed, errors = 0, []
    with open(path, "rb") as fh:
        for raw, _ in NMEAReader(fh, quitonerror=1, validate=1, errorhandler=errors.append):
            if raw is not None:
                parsed += 1
    others: Counter = Counter()
    for line in path.read_bytes().splitlines():
        line = line.strip()
        if line[:1] in (b"$", b"!") and line[:2] not in NMEA_HDR:
            others["".join(c if c.isprintable() and c not in "|`" else "?" for c in line[:3].decode("latin-1"))] += 1
    label = f"NMEA {parsed + len(errors)} (pynmeagps" + (f"; {len(errors)} it rejects" if errors else "") + ")"
    if others:
        label += f" + {sum(others.values())} it does not take (" + ", ".join(
            f"{k} {v}" for k, v in sorted(others.items())) + ")"
    return label, parsed + len(errors) + sum(others.values())


def library_count(path: Path, fmt: str | None) -> tuple[str, int | None]:
    """Messages in the file as the format's own library counts them (by protocol where mixed), and the total."""
    try:
        if fmt == "nmea":
            return nmea_library_count(path)
        if fmt in ("ubx", "rtcm3"):
            from pyubx2 import UBXReader

            counts: Counter = Counter()
            with open(path, "rb") as fh:
                for raw, _ in UBXReader(fh, protfilter=7, quitonerror=0, validate=0, msgmode=0, parsing=False):
                    if raw is None:
                        continue
                    kind = "UBX" if raw[:2] == b"\xb5\x62" else "RTCM" if raw[:1] == b"\xd3" else "NMEA"
                    counts[kind] += 1
            return ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + " (pyubx2)", sum(counts.values())
        if fmt == "ulog":
            from pyulog import ULog

            u = ULog(str(path))
            n = sum(len(d.data['timestamp']) for d in u.data_list)
            return f"{n} samples in {len(u.data_list)} topics (pyulog)", n
        if fmt == "dataflash":
            from pymavlink.DFReader import DFReader_binary

            r = DFReader_binary(str(path))
            n = 0
            while r.recv_msg() is not None:
                n += 1
            return f"{n} records (pymavlink)", n
        if fmt == "tlog":
            from pymavlink import mavutil

            m = mavutil.mavlink_connection(str(path))
            n = 0
            while m.recv_match() is not None:
                n += 1
            return f"{n} messages (pymavlink)", n
        if fmt == "rosbag":
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore

            store = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
            with AnyReader([path], default_typestore=store) as r:
                n = sum(c.msgcount for c in r.connections)
                return f"{n} messages in {len(r.connections)} topics (rosbags)", n
    except Exception as exc:  # the library's own failure is a finding, not a crash of this script
        first = (str(exc).splitlines() or [""])[0][:60]
        return f"library failed: {type(exc).__name__} {first}".strip(), None
    return "-", None


def run_cli(argv: list[str]) -> tuple[int, str, float, bool]:
    """``vesselid <argv>`` in this process: exit code, first error line, seconds, traceback seen."""
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    tb = False
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli_main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
        except Exception as exc:  # an uncaught exception is exactly what this benchmark looks for
            code, tb = 99, True
            err.write(f"TRACEBACK {type(exc).__name__}: {exc}\n")
    dt = time.perf_counter() - t0
    text = err.getvalue() + out.getvalue()
    tb = tb or "Traceback" in text or bool(_EXC_NAME.search(err.getvalue()))
    first = next((ln for ln in err.getvalue().splitlines() if ln.startswith(("error:", "TRACEBACK"))), "")
    if tb and not first:
        first = next((ln for ln in err.getvalue().splitlines() if _EXC_NAME.search(ln)), "Traceback")
    return code, first, dt, tb


def fit_subprocess(path: Path) -> tuple[int, str, float, bool, float]:
    """``vesselid fit`` in its own process: exit code, first error line, wall [s], traceback seen, CPU [s].

    The CPU time (user + system of the process and the compilers it waited for) is given next to
    the wall time because the machine is shared: the wall time grows with the load, the CPU time
    does not. The 300 s limit is on the wall time.
    """
    import resource

    def cpu() -> float:
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return ru.ru_utime + ru.ru_stime

    c0 = cpu()
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        # Own process group: on a timeout the compiler a JIT may have started is stopped too.
        proc = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "fit", "--vessel", str(VESSEL), str(path),
                                 "--json", str(Path(d) / "fit.json")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, cwd=ROOT, start_new_session=True,
                                # Its own temporary folder, so a killed JIT leaves nothing behind.
                                env={**os.environ, "PYTHONPATH": str(ROOT), "CI": "1", "TMPDIR": d})
        try:
            out, err = proc.communicate(timeout=FIT_LIMIT_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            return 124, f"timeout after {FIT_LIMIT_S:g} s", time.perf_counter() - t0, False, cpu() - c0
        dt = time.perf_counter() - t0
        res = subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
    first = next((ln for ln in res.stderr.splitlines() if ln.startswith("error:")), "")
    tb = "Traceback" in res.stderr + res.stdout or bool(_EXC_NAME.search(res.stderr))
    if tb and not first:
        # No 'error:' line: name the exception's last line, so the problem list says what escaped.
        first = next((ln.strip() for ln in reversed(res.stderr.splitlines()) if ln.strip()), "no output on stderr")
    return res.returncode, first, dt, tb, cpu() - c0


def _short(s: str, n: int = 110) -> str:
    s = s.replace("|", "/").replace(str(ROOT) + "/", "").replace(tempfile.gettempdir() + "/", "")
    return s if len(s) <= n else s[:n - 3] + "..."


def main(argv=None) -> int:
    """Run every real file through ingest, align, segment and fit; print the table.

    Parameters
    ----------
    argv : sequence of str, optional
        ``--mirror``, ``--cache``, ``--only``.
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mirror", type=Path, default=Path("/work/.mirror"), help="local git mirrors (owner+name/repo)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vesselid-realfiles")
    ap.add_argument("--only", default="", help="only files whose path contains this")
    ap.add_argument("--counts-only", action="store_true", help="only the message accounting, no commands")
    args = ap.parse_args(argv)
    files: list[tuple[str, Path]] = [(p.parent.name, p) for p in sorted(DATA.glob("*/*")) if p.name != "SOURCE.md"]
    skipped_remote = []
    for repo, commit, path, _ in REMOTE:
        got = fetch_remote(repo, commit, path, args.mirror, args.cache)
        if got is None:
            skipped_remote.append(f"{repo}:{path}")
        else:
            files.append((repo.split("/")[1] + " (fetched)", got))
    files = [f for f in files if args.only in str(f[1])]
    print(f"Real files: {len(files)} from {len({r.split(' ')[0] for r, _ in files})} repositories"
          + (f"; not available (no mirror, no network): {', '.join(skipped_remote)}" if skipped_remote else ""))
    print()
    print("| repository | file | bytes | format (sniffed) | messages (library) | read | skipped | read + skipped "
          "messages - library | ingest | align | segment | fit | fit wall [s] | fit CPU [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    problems = []
    outcome: Counter = Counter()
    for repo, path in files:
        try:
            fmt, _ = sniff(path)
        except OSError:
            fmt = None
        lib, lib_n = library_count(path, fmt)
        accounted = "-"
        try:
            log = read_log(path)
            n_read, n_skip = sum(log.summary.read.values()), sum(log.summary.skipped.values())
            # Messages only: bytes and lines that hold no message (garbage, bad checksums) are
            # counted by the reader but not by the libraries.
            n_msgs = n_read + sum(v for k, v in log.summary.skipped.items()
                                  if not any(w in k.lower() for w in _NOT_MESSAGES))
            if lib_n is not None:
                accounted = "=" if n_msgs == lib_n else f"{n_msgs - lib_n:+d}"
        except VesselidError:
            n_read = n_skip = "-"
        except Exception as exc:  # noqa: BLE001 - counted as a defect below
            n_read = n_skip = f"TRACEBACK {type(exc).__name__}"
        if args.counts_only:
            print(f"| {repo} | `{path.name}` | {path.stat().st_size} | {fmt or '-'} | {lib} | {n_read} | {n_skip} | "
                  f"{accounted} |")
            continue
        cells = []
        tracebacks = []
        stop = False
        n_seg = 0
        seg_json = Path(tempfile.gettempdir()) / "vesselid-realfiles-seg.json"
        for cmd in ("ingest", "align", "segment"):
            if stop:
                cells.append("(not reached)")
                continue
            seg_json.unlink(missing_ok=True)
            # segment with the vessel, as fit runs it (its actuator map turns logged outputs into inputs).
            extra = ["--vessel", str(VESSEL), "--json", str(seg_json)] if cmd == "segment" else []
            code, first, _, tb = run_cli([cmd, str(path), *extra])
            if tb:
                tracebacks.append(f"{cmd}: {first}")
            if code == 0:
                cells.append("ok")
                if cmd == "segment" and seg_json.is_file():
                    import json

                    n_seg = len(json.loads(seg_json.read_text()).get("segments", []))
                    cells[-1] = f"ok ({n_seg} segments)"
            else:
                cells.append(f"exit {code}: {_short(first)}")
                stop = True
                if "expected" not in first or "found" not in first:
                    problems.append(f"{path.name} {cmd}: error does not name expected/found: {first}")
        if cells[-1].startswith("ok"):
            code, first, dt, tb, cpu_s = fit_subprocess(path)
        else:  # an earlier command stopped: fit stops at the same point, in this process
            code, first, dt, tb = run_cli(["fit", "--vessel", str(VESSEL), str(path), "--json", os.devnull])
            cpu_s = float("nan")
        if tb:
            tracebacks.append(f"fit: {first}")
        fit_cell = "ok" if code == 0 else f"exit {code}: {_short(first, 80)}"
        if dt > FIT_LIMIT_S or code == 124:
            problems.append(f"{path.name}: fit took {dt:.0f} s")
        if tracebacks:
            problems.append(f"{path.name}: exception reached the user: {'; '.join(tracebacks)}")
        outcome["ingest ok" if cells[0] == "ok" else "ingest error"] += 1
        outcome["fit ok" if code == 0 else "fit error"] += 1
        cpu_text = "-" if math.isnan(cpu_s) else f"{cpu_s:.1f}"
        print(f"| {repo} | `{path.name}` | {path.stat().st_size} | {fmt or '-'} | {lib} | {n_read} | {n_skip} | "
              f"{accounted} | "
              f"{' | '.join(cells)} | {fit_cell} | {dt:.1f} | {cpu_text} |")
    print()
    print(f"Outcome: {dict(sorted(outcome.items()))}; problems: {len(problems)}")
    for p in problems:
        print(f"- {p}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

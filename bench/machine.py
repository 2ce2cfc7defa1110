"""What the benchmarks ran on, and how much CPU and memory a process used (read from /proc).

``describe()`` gives the machine (cores, CPU model), Python and library versions and the date for
the head of RESULTS.md. The /proc readers need no third-party package: process CPU time from
``os.times``, per-thread CPU time from ``/proc/self/task/<tid>/stat`` (named by the kernel's
``comm``: zenoh's runtime threads carry their own names), resident memory from
``/proc/<pid>/status``.

Imports: the standard library only (library versions through importlib.metadata).
"""

from __future__ import annotations

import datetime
import os
import platform
import shutil
import subprocess
from dataclasses import dataclass
from importlib import metadata

LIBRARIES = ("eclipse-zenoh", "pymodbus", "python-can", "canopen", "pydantic", "canopen-gateway")
_CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def describe() -> dict[str, str]:
    """Machine, interpreter and library versions, date (UTC)."""
    info = {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": cpu_model(),
        "cores": str(os.cpu_count()),
        "kernel": platform.release(),
        "python": f"{platform.python_implementation()} {platform.python_version()}",
    }
    for lib in LIBRARIES:
        try:
            info[lib] = metadata.version(lib)
        except metadata.PackageNotFoundError:
            info[lib] = "not installed"
    gcc = shutil.which("gcc")
    if gcc:
        out = subprocess.run([gcc, "--version"], capture_output=True, text=True, check=False)
        info["gcc"] = out.stdout.splitlines()[0] if out.stdout else "unknown"
    return info


def load_average() -> str:
    try:
        with open("/proc/loadavg", encoding="ascii") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "unknown"


def process_cpu_s() -> float:
    """User + system CPU seconds of this process (all threads)."""
    t = os.times()
    return t.user + t.system


def rss_kib(pid: int | str = "self") -> dict[str, int]:
    """VmRSS (now) and VmHWM (peak) in KiB of a process."""
    out: dict[str, int] = {}
    with open(f"/proc/{pid}/status", encoding="ascii") as f:
        for line in f:
            key, _, rest = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                out[key] = int(rest.split()[0])
    return out


@dataclass(frozen=True)
class ThreadCpu:
    tid: int
    name: str
    cpu_s: float


def threads_cpu(pid: int | str = "self") -> list[ThreadCpu]:
    """CPU seconds (user + system) of every thread of a process, by kernel thread name."""
    out = []
    base = f"/proc/{pid}/task"
    for tid in os.listdir(base):
        try:
            with open(f"{base}/{tid}/stat", encoding="ascii", errors="replace") as f:
                stat = f.read()
        except OSError:
            continue  # the thread ended meanwhile
        # the name is in parentheses and may contain spaces: split after the last ')'
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        utime, stime = int(fields[11]), int(fields[12])  # fields 14 and 15 of proc(5)
        out.append(ThreadCpu(int(tid), name, (utime + stime) / _CLK_TCK))
    return out

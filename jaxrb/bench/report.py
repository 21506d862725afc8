"""Markdown output shared by the benchmarks: tables, number formats, machine header."""

from __future__ import annotations

import math
import os
import platform
import sys
import time
from typing import Any, Iterable, Optional, Sequence

import jax

from jaxrb.compile import XLA_FLAGS_STATUS


def markdown_table(headers: Sequence[str], rows: Iterable[Sequence[Any]],
                   align: Optional[Sequence[str]] = None) -> str:
    """A GitHub-flavoured Markdown table, columns padded for reading as plain text.

    Args:
        headers: column titles.
        rows: one sequence of cells per row; cells are turned into text with
            ``str`` (format numbers before, e.g. with :func:`fmt_sci`).
        align: per column ``"l"``, ``"r"`` or ``"c"``; default: left for the
            first column, right for the others.

    Returns:
        The table, without a trailing newline.
    """
    headers = [_cell(h) for h in headers]
    body = [[_cell(c) for c in row] for row in rows]
    for row in body:
        if len(row) != len(headers):
            raise ValueError(f"markdown_table: row {row} has {len(row)} cells, "
                             f"expected {len(headers)}")
    if align is None:
        align = ["l"] + ["r"] * (len(headers) - 1)
    widths = [max([len(h)] + [len(row[i]) for row in body] + [3]) for i, h in enumerate(headers)]

    def line(cells):
        padded = [c.rjust(w) if a == "r" else c.center(w) if a == "c" else c.ljust(w)
                  for c, w, a in zip(cells, widths, align)]
        return "| " + " | ".join(padded) + " |"

    rule = {"l": ":{}", "r": "{}:", "c": ":{}:"}
    separator = "| " + " | ".join(
        rule[a].format("-" * (w - (2 if a == "c" else 1))) for w, a in zip(widths, align)) + " |"
    return "\n".join([line(headers), separator] + [line(row) for row in body])


def _cell(value) -> str:
    return str(value).replace("|", "\\|").replace("\n", " ")


def fmt_sci(value, digits: int = 2) -> str:
    """Compact scientific notation (``1.23e-04``); ``inf``/``nan``/``—`` pass through."""
    if value is None:
        return "—"
    value = float(value)
    if math.isnan(value):
        return "nan"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    if value == 0.0:
        return "0"
    return f"{value:.{digits}e}"


def fmt_fixed(value, digits: int = 3) -> str:
    """Fixed-point with ``digits`` decimals; ``None`` is an em dash."""
    if value is None:
        return "—"
    value = float(value)
    if not math.isfinite(value):
        return fmt_sci(value)
    return f"{value:.{digits}f}"


def fmt_si(value, unit: str = "", digits: int = 3) -> str:
    """Engineering prefix (k, M, G) for large rates: ``fmt_si(4.2e6, '/s') -> '4.20 M/s'``."""
    if value is None:
        return "—"
    value = float(value)
    if not math.isfinite(value):
        return fmt_sci(value)
    for factor, prefix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= factor:
            return f"{value / factor:.{digits - 1}f} {prefix}{unit}"
    return f"{value:.{digits - 1}f} {unit}".rstrip()


def fmt_step(h: float) -> str:
    """A time step as ``1/60`` when it is the reciprocal of an integer, else ``%g``."""
    inverse = 1.0 / h
    if abs(inverse - round(inverse)) < 1e-9 * inverse:
        return f"1/{int(round(inverse))}"
    return f"{h:g}"


#: The ``/proc/cpuinfo`` flags :func:`machine_info` reports: the vector units XLA's CPU code can use.
VECTOR_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512_bf16", "amx_tile")


def cpuinfo(path: str = "/proc/cpuinfo") -> dict:
    """The first processor's fields in ``path`` (name -> text); empty where there is no such file."""
    fields = {}
    try:
        with open(path) as handle:
            for text in handle:
                if not text.strip():
                    break  # the first processor's block ends at a blank line
                name, _, value = text.partition(":")
                fields[name.strip()] = value.strip()
    except OSError:
        pass
    return fields


def machine_info() -> dict:
    """Facts about the machine and software the benchmark ran on."""
    devices = jax.devices()
    try:
        import jaxlib
        jaxlib_version = jaxlib.__version__
    except (ImportError, AttributeError):  # pragma: no cover
        jaxlib_version = "?"
    try:
        affinity = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover
        affinity = None
    cpu = cpuinfo()
    processor = cpu.get("model name", platform.processor() or platform.machine())
    # Two hosts that both call themselves "AMD EPYC" ran the same commit's box
    # drop at 11.3 M and 3.9 M body-steps/s (docs/design.md, 'How to read the numbers'):
    # the clock and vector units are what tell such hosts apart.
    extensions = " ".join(flag for flag in VECTOR_FLAGS if flag in cpu.get("flags", "").split())
    try:
        load = "{:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except (AttributeError, OSError):  # pragma: no cover
        load = "?"
    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "platform": platform.platform(),
        "processor": processor,
        "cpu count": f"{os.cpu_count()}" + (f" ({affinity} usable)" if affinity else ""),
        "cpu MHz, cache": f"{cpu.get('cpu MHz', '?')}, {cpu.get('cache size', '?')}",
        "cpu vector extensions": extensions or "(none listed)",
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "jaxlib": jaxlib_version,
        "backend": jax.default_backend(),
        "devices": ", ".join(str(d) for d in devices),
        "load average (1, 5, 15 min) at start": load,
        "x64 enabled": str(bool(jax.config.jax_enable_x64)),
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", "(unset)"),
        "XLA_FLAGS at import jaxrb": XLA_FLAGS_STATUS + " (see jaxrb.compile.use_xla_cpu_flags)",
    }


def bullet_list(items: dict) -> str:
    """``- **key**: value`` lines."""
    return "\n".join(f"- **{key}**: {value}" for key, value in items.items())


class Report:
    """Accumulates Markdown sections; ``str(report)`` is the document."""

    def __init__(self, title: str):
        self.parts = [f"# {title}"]

    def heading(self, text: str, level: int = 2):
        self.parts.append("#" * level + " " + text)

    def paragraph(self, text: str):
        self.parts.append(text.strip())

    def table(self, headers, rows, align=None):
        self.parts.append(markdown_table(headers, rows, align))

    def extend(self, markdown: str):
        """Append a ready-made block of Markdown (e.g. from a benchmark's section)."""
        self.parts.append(markdown.strip())

    def __str__(self) -> str:
        return "\n\n".join(self.parts) + "\n"

    def write(self, path):
        with open(path, "w", encoding="utf-8") as handle:
            handle.write(str(self))

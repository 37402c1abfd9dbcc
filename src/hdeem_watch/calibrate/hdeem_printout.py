"""Parse real HDEEM printouts: ``checkHdeem`` output and lines printed after ``hdeem_get_stats``.

Two shapes occur in the Taurus captures (``tests/data/taurus``):

* ``checkHdeem``: sections ``==== Instantaneous values ====`` (``NAME value``),
  ``==== HDEEM statistics ====`` (stats times, ``Blade values for stats : N``, ``VR values for
  stats : N``, optionally ``Duration for stats (s)`` and ``Real blade/vr freq (#Measure/s)``, then a
  ``Max (W) Min (W) Average (W) Energy (J)`` table) and ``==== HDEEM statistics total from power
  awake ====`` (``Average (W) Energy (J)`` table).
* benchmark lines: ``DDR_AB   The average power:   1.198 W  Max power    1.750  Min power    0.750``
  grouped under a ``//...`` comment naming the API (``get_stats`` or ``hdeem_get_stats_total``);
  with the total API min/max read 0, which means unknown (NaN here).

Where the duration/frequency lines are missing, the sample rates are derived from the table
(``rate = samples × average / energy``, marked ``rates_derived``).

Example:
    >>> p = parse_printout("//x API: get_stats\\nBLADE The average power : 100.5 W  Max power 101.0  Min power 99.0\\n")
    >>> p.blocks[0].sensors["BLADE"].average_w
    100.5
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

from hdeem_watch.channels import DRAM_CHANNELS, normalise_channel_name
from hdeem_watch.errors import InputError

NAN = math.nan
_NUM = r"[-+]?\d+(?:\.\d+)?"
_LINE = re.compile(
    rf"^\s*(?P<name>[A-Za-z][\w ]*?)\s+The average power\s*:\s*(?P<avg>{_NUM})\s*W\s+Max power\s+(?P<max>{_NUM})"
    rf"\s+Min power\s+(?P<min>{_NUM})\s*$"
)
_SECTION = re.compile(r"^\s*====\s*(?P<title>.*?)\s*====\s*$")
_KEYVAL = re.compile(r"^\s*(?P<key>[^:]+?)\s*:\s*(?P<value>.+?)\s*$")
_REAL = re.compile(r"^\s*real\s+(?P<m>\d+)m(?P<s>\d+(?:\.\d+)?)s\s*$")


@dataclass(frozen=True)
class SensorStats:
    """One sensor's row. Unknown values are NaN."""

    channel: str
    average_w: float = NAN
    max_w: float = NAN
    min_w: float = NAN
    energy_j: float = NAN
    instant_w: float = NAN


@dataclass
class StatsBlock:
    """One statistics block.

    Attributes:
        kind: ``"stats"`` (since start), ``"stats_total"`` (since power-on) or ``"instant"``.
        label: the comment or section title it came from.
        line: 1-based line number where it starts.
        sensors: per channel (normalised names), in printed order.
        blade_samples, vr_samples: sample counts (``None`` if not printed).
        duration_s: measurement duration (NaN if unknown).
        blade_rate_hz, vr_rate_hz: sample rates, printed or derived (NaN if neither).
        rates_derived: the rates were derived from samples × average / energy.
        time_blade, time_vr: the printed stats times (text, ``""`` if absent).
        real_s: wall time of the benchmark (``real`` line after the block), NaN if absent.
    """

    kind: str
    label: str
    line: int
    sensors: dict[str, SensorStats] = field(default_factory=dict)
    blade_samples: int | None = None
    vr_samples: int | None = None
    duration_s: float = NAN
    blade_rate_hz: float = NAN
    vr_rate_hz: float = NAN
    rates_derived: bool = False
    time_blade: str = ""
    time_vr: str = ""
    real_s: float = NAN

    def dram_energy_j(self) -> float:
        """Energy of the four DIMM pairs (J): printed energies, else average × duration; NaN if neither.

        This is the ``measured_j`` of a calibration run (RUNS.json) imported from a printout.
        """
        rows = [self.sensors[c] for c in DRAM_CHANNELS if c in self.sensors]
        if len(rows) != len(DRAM_CHANNELS):
            return NAN
        if all(math.isfinite(r.energy_j) for r in rows):
            return float(sum(r.energy_j for r in rows))
        if math.isfinite(self.duration_s) and all(math.isfinite(r.average_w) for r in rows):
            return float(sum(r.average_w for r in rows) * self.duration_s)
        return NAN


@dataclass(frozen=True)
class Printout:
    """All blocks of a file, in order."""

    blocks: list[StatsBlock]

    def of_kind(self, kind: str) -> list[StatsBlock]:
        """The blocks of one kind."""
        return [b for b in self.blocks if b.kind == kind]

    def to_dict(self) -> dict:
        """JSON-ready form (NaN → ``None``)."""

        def clean(v: object) -> object:
            return None if isinstance(v, float) and math.isnan(v) else v

        out = []
        for b in self.blocks:
            d = {k: clean(v) for k, v in asdict(b).items() if k != "sensors"}
            d["sensors"] = {n: {k: clean(v) for k, v in asdict(s).items()} for n, s in b.sensors.items()}
            out.append(d)
        return {"blocks": out}


def _float(text: str, where: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{where}: {text!r} is not a number") from None


def _derive_rates(block: StatsBlock) -> None:
    """Fill missing rates from samples × average / energy (energy = average × samples / rate)."""
    if not math.isnan(block.blade_rate_hz) and not math.isnan(block.vr_rate_hz):
        return
    rows = list(block.sensors.values())
    for is_blade in (True, False):
        n = block.blade_samples if is_blade else block.vr_samples
        group = [r for r in rows if (r.channel == "BLADE") == is_blade and r.energy_j > 0 and r.average_w > 0]
        if not n or not group:
            continue
        rate = n * sum(r.average_w for r in group) / sum(r.energy_j for r in group)
        if is_blade and math.isnan(block.blade_rate_hz):
            block.blade_rate_hz, block.rates_derived = rate, True
        elif not is_blade and math.isnan(block.vr_rate_hz):
            block.vr_rate_hz, block.rates_derived = rate, True
    if math.isnan(block.duration_s) and block.blade_samples and not math.isnan(block.blade_rate_hz):
        block.duration_s = block.blade_samples / block.blade_rate_hz


def parse_printout(text: str, where: str = "printout") -> Printout:
    """Parse ``checkHdeem``/``get_stats`` printouts (any mix, any order).

    Raises:
        InputError: ``<where>:<line>: ...`` for a recognised line whose values are malformed, or a
            file with no statistics at all.
    """
    blocks: list[StatsBlock] = []
    current: StatsBlock | None = None
    table_cols: list[str] = []
    comment = ""
    for lineno, raw in enumerate(text.splitlines(), 1):
        at = f"{where}:{lineno}"
        line = raw.rstrip()
        if not line.strip():
            continue
        if line.lstrip().startswith("//"):
            comment = line.strip()[2:].strip()
            current, table_cols = None, []
            continue
        m = _LINE.match(line)
        if m:
            kind = "stats_total" if "total" in comment.lower() else "stats"
            if current is None or current.kind not in ("stats", "stats_total") or table_cols:
                current, table_cols = StatsBlock(kind, comment, lineno), []
                blocks.append(current)
            name = normalise_channel_name(m["name"])
            mx, mn = _float(m["max"], at), _float(m["min"], at)
            if kind == "stats_total" and mx == 0 and mn == 0:
                mx = mn = NAN  # get_stats_total reads 0 for min/max: unknown
            current.sensors[name] = SensorStats(name, average_w=_float(m["avg"], at), max_w=mx, min_w=mn)
            continue
        m = _REAL.match(line)
        if m:
            if blocks:
                blocks[-1].real_s = int(m["m"]) * 60 + _float(m["s"], at)
            continue
        m = _SECTION.match(line)
        if m:
            title = m["title"]
            low = title.lower()
            kind = "instant" if "instantaneous" in low else "stats_total" if "total" in low else "stats"
            current, table_cols = StatsBlock(kind, title, lineno), []
            blocks.append(current)
            continue
        if current is None:
            continue  # free text outside any block (user/sys times, notes)
        words = line.split()
        if current.kind == "instant":
            if len(words) == 2:
                name = normalise_channel_name(words[0])
                current.sensors[name] = SensorStats(name, instant_w=_float(words[1], at))
            continue
        if ("(W)" in line or "(J)" in line) and ":" not in line:
            table_cols = [c.split("(")[0].strip().lower() for c in re.findall(r"[A-Za-z]+\s*\([WJ]\)", line)]
            continue
        if ":" in line and not table_cols:
            kv = _KEYVAL.match(line)
            if kv:
                _key_value(current, kv["key"].lower(), kv["value"], at)
            continue
        if table_cols:
            if len(words) != len(table_cols) + 1:
                raise InputError(f"{at}: expected a sensor name and {len(table_cols)} numbers "
                                 f"({', '.join(table_cols)}), got {line.strip()!r}")
            name = normalise_channel_name(words[0])
            values = dict(zip(table_cols, (_float(w, at) for w in words[1:])))
            current.sensors[name] = SensorStats(
                name, average_w=values.get("average", NAN), max_w=values.get("max", NAN),
                min_w=values.get("min", NAN), energy_j=values.get("energy", NAN))
    if not any(b.sensors for b in blocks):
        raise InputError(f"{where}: no HDEEM statistics found; expected checkHdeem or get_stats output")
    for block in blocks:
        if block.kind != "instant" and block.blade_samples:
            _derive_rates(block)
    return Printout(blocks=[b for b in blocks if b.sensors])


def _key_value(block: StatsBlock, key: str, value: str, at: str) -> None:
    if key.startswith("time of"):
        if "blade" in key:
            block.time_blade = value
        elif "vr" in key:
            block.time_vr = value
    elif key.startswith("blade values"):
        block.blade_samples = int(_float(value, at))
    elif key.startswith("vr") and "values" in key:
        block.vr_samples = int(_float(value, at))
    elif key.startswith("duration"):
        block.duration_s = _float(value, at)
    elif key.startswith("real blade freq"):
        block.blade_rate_hz = _float(value, at)
    elif key.startswith("real vr"):
        block.vr_rate_hz = _float(value, at)


def read_printout(path: str | Path) -> Printout:
    """Parse a printout file (see :func:`parse_printout`).

    Raises:
        InputError: unreadable file or malformed content (with the line number).
    """
    try:
        text = Path(path).read_text(errors="replace")
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return parse_printout(text, where=str(path))

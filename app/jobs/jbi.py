"""Yaskawa INFORM job files (``.JBI``): read the positions and who moves to them, write the job back.

The format, as the Motoman manuals give it (NX100/DX100 "Job Data Format"; Motoman knowledge base "INFORM
Header Fields") and as the cell lab's own job writer and sample jobs use it (rpiRobotics/dx200_motion_progam_exec)::

    /JOB
    //NAME R1-R2
    //POS
    ///NPOS 2,0,0,0,0,0             C, BC, EC, P, BP, EX counts
    ///TOOL 0                       tool of the positions that follow
    ///POSTYPE PULSE                PULSE | BASE | ROBOT | TOOL | USER | MTOOL
    ///PULSE                        (or ///RECTAN + ///RCONF l,m,n,o,p,q,... for Cartesian data)
    C00000=-6744,-46438,-34826,-14046,-21223,6588
    ///TOOL 1
    C00001=-6022,-65326,-52845,3,-2902,-16
    //INST
    ///DATE 2023/02/06 16:30
    ///ATTR SC,RW
    ///GROUP1 RB1                   control group 1 (a robot, optionally with BS/ST axes)
    ///GROUP2 RB2
    NOP
    MOVJ C00000 VJ=10.00  +MOVJ C00001 VJ=10.00
    END

C positions are robot teaching positions (pulses, or X,Y,Z [mm], Rx,Ry,Rz [deg] for Cartesian types), BC base
axis, EC station axis positions. In a move line each ``+``-joined segment is the next control group; a C in
segment k belongs to the k-th group's robot (with two robots in one group, ``///GROUP1 RB1,RB2``, the j-th C of
the segment to the j-th robot: this parser's reading of that case). A job without ``///GROUP1`` is RB1's.

Every line is kept as its raw bytes with its own line ending (controllers write CRLF), so :func:`write_job`
reproduces the file byte for byte except the lines it is told to replace.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Literal

from calibration.data.files import read_input_bytes
from calibration.errors import CellCalError

__all__ = ["JOB_POSTYPES", "Job", "JobError", "JobPosition", "parse_job", "pulse_job", "read_job", "write_job"]

JOB_POSTYPES = ("PULSE", "BASE", "ROBOT", "TOOL", "USER", "MTOOL")
PosType = Literal["PULSE", "BASE", "ROBOT", "TOOL", "USER", "MTOOL"]
MAX_JOB_BYTES = 64 * 1024 * 1024
_POS_LINE = re.compile(r"^(C|BC|EC|P|BP|EX)(\d+)=(.*)$")
_MOVE = re.compile(r"^S?MOV[JLCS]$")
_C_REF = re.compile(r"^C(\d{5})$")
_SEGMENT = re.compile(r"\s\+(?=\s*[A-Z])")
_INT = re.compile(r"^[+-]?\d+$")
_NUM = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)$")


class JobError(CellCalError):
    """A job file is unusable or one of its points cannot be compensated; nothing is written.

    Args:
        path: the job file.
        line: 1-based line number, or None when the problem is not tied to a line.
        reason: what is wrong and what was expected.
    """

    def __init__(self, path: str | Path, line: int | None, reason: str) -> None:
        self.path, self.line, self.reason = str(path), line, reason
        super().__init__(f"{self.path}{'' if line is None else f', line {line}'}: {reason}")


@dataclass(frozen=True)
class JobPosition:
    """One robot teaching position (``Cnnnnn=``) of the //POS section.

    Attributes:
        name: ``C00003``.
        line: 1-based line number of its definition.
        postype: the ``///POSTYPE`` in force (PULSE or a Cartesian type).
        values: the numbers after ``=``: pulses, or X, Y, Z [mm], Rx, Ry, Rz [deg] (and Re when given).
        decimals: digits after the point of each value as written (kept when the value is rewritten).
        tool: the ``///TOOL`` in force, None before any.
        rconf: the ``///RCONF`` flags in force for Cartesian data, None for pulses.
        unit: the robot that moves to it (``RB1``), from the move instructions.
        group: 1-based control group of that robot.
    """

    name: str
    line: int
    postype: PosType
    values: tuple[float, ...]
    decimals: tuple[int, ...]
    tool: int | None = None
    rconf: tuple[int, ...] | None = None
    unit: str = ""
    group: int = 0


@dataclass(frozen=True)
class Job:
    """A parsed job: its raw lines, its robot positions and the control groups."""

    path: Path
    raw_lines: tuple[bytes, ...]
    name: str
    groups: tuple[tuple[str, ...], ...]
    positions: tuple[JobPosition, ...]
    variables: tuple[tuple[str, int], ...] = field(default=())  # (P/BP/EX name, line): kept as written

    def text(self, line: int) -> str:
        """Line ``line`` (1-based) without its line ending."""
        return _decode(self.raw_lines[line - 1]).rstrip("\r\n")


def _decode(raw: bytes) -> str:
    return raw.decode("latin-1")


def read_job(path: str | Path) -> Job:
    """Read and parse a job file (bytes kept); every problem is a :class:`JobError` naming the file and line."""
    path = Path(path)
    try:
        if path.is_dir():
            raise JobError(path, None, "expected a job file, found a directory")
        data = read_input_bytes(path, MAX_JOB_BYTES)  # a FIFO or a device is refused, a larger file too
    except FileNotFoundError:
        raise JobError(path, None, "job file not found") from None
    except OSError as e:
        raise JobError(path, None, f"cannot read ({e.__class__.__name__}: {e.strerror or e})") from e
    return parse_job(data, path)


def parse_job(data: bytes, path: str | Path = "<job>") -> Job:
    """Parse the bytes of a job file."""
    path = Path(path)
    if b"\0" in data:
        raise JobError(path, None, "binary data (NUL bytes); expected an INFORM job (text)")
    raw = tuple(data.splitlines(keepends=True))
    texts = [_decode(r).rstrip("\r\n") for r in raw]
    if not texts or texts[0].strip() != "/JOB":
        raise JobError(path, 1, "expected '/JOB' on the first line of an INFORM job")
    name = next((t[7:].strip() for t in texts if t.startswith("//NAME ")), "")
    pos_end = _section(texts, "//INST", path)
    if "//POS" not in (t.strip() for t in texts[:pos_end]):
        raise JobError(path, None, "no //POS section before //INST")
    positions, variables = _positions(texts, pos_end, path)
    groups, refs = _instructions(texts, pos_end, path)
    job = Job(path, raw, name, groups, _assign(positions, refs, groups, path), tuple(variables))
    _check_npos(texts, pos_end, positions, variables, path)
    return job


#: The kinds ``///NPOS`` counts, in its order.
NPOS_KINDS = ("C", "BC", "EC", "P", "BP", "EX")


def _check_npos(texts: list[str], end: int, positions: list[JobPosition], variables: list[tuple[str, int]],
                path: Path) -> None:
    """Refuse a job whose ``///NPOS`` header disagrees with the positions the //POS section holds: the controller
    refuses to load such a job, and a count that disagrees means positions were lost or pasted in by hand."""
    line = next((i for i in range(end) if texts[i].strip().startswith("///NPOS")), None)
    if line is None:
        return
    declared = _ints(texts[line].strip()[7:], line + 1, path, "///NPOS")
    found = {k: 0 for k in NPOS_KINDS}
    found["C"] = len(positions)
    for name, _ in variables:
        kind = name.rstrip("0123456789")
        found[kind] = found.get(kind, 0) + 1
    counts = tuple(found[k] for k in NPOS_KINDS)
    if declared[:len(NPOS_KINDS)] + (0,) * (len(NPOS_KINDS) - len(declared)) != counts:
        raise JobError(path, line + 1, f"///NPOS {','.join(map(str, declared))} disagrees with the //POS section, "
                                       f"which holds {', '.join(f'{n} {k}' for k, n in zip(NPOS_KINDS, counts))}")


def _section(texts: list[str], marker: str, path: Path) -> int:
    for i, t in enumerate(texts):
        if t.strip() == marker:
            return i
    raise JobError(path, None, f"no {marker} line; expected an INFORM job with {marker}")


def _positions(texts: list[str], end: int, path: Path) -> tuple[list[JobPosition], list[tuple[str, int]]]:
    """The C positions of the //POS section, with the POSTYPE/TOOL/RCONF in force at each."""
    postype: str = "PULSE"
    tool: int | None = None
    rconf: tuple[int, ...] | None = None
    out: list[JobPosition] = []
    variables: list[tuple[str, int]] = []
    for i in range(end):
        t, n = texts[i].strip(), i + 1
        if t.startswith("///POSTYPE"):
            postype = t[10:].strip()
            if postype not in JOB_POSTYPES:
                raise JobError(path, n, f"unknown ///POSTYPE {postype!r}; valid: {', '.join(JOB_POSTYPES)}")
        elif t.startswith("///TOOL"):
            tool = _ints(t[7:], n, path, "///TOOL")[0]
        elif t.startswith("///RCONF"):
            rconf = _ints(t[8:], n, path, "///RCONF")
        elif t.startswith("///PULSE"):
            rconf = None
        m = _POS_LINE.match(t)
        if not m:
            if t and not t.startswith("/"):
                raise JobError(path, n, f"malformed line in //POS: {t[:40]!r}; expected NAME=values or ///...")
            continue
        kind, fields = m.group(1), [f.strip() for f in m.group(3).split(",")]
        if kind != "C":
            variables.append((kind + m.group(2), n))
            continue
        out.append(_position(kind + m.group(2), n, postype, fields, tool, rconf, path))
    return out, variables


def _position(name: str, n: int, postype: str, fields: list[str], tool: int | None,
              rconf: tuple[int, ...] | None, path: Path) -> JobPosition:
    if len(name) != 6:
        raise JobError(path, n, f"malformed position name {name!r}; expected C and 5 digits")
    pulse = postype == "PULSE"
    ok = _INT if pulse else _NUM
    if len(fields) not in ((6,) if pulse else (6, 7)) or not all(ok.match(f) for f in fields):
        what = "6 integer pulses" if pulse else "X,Y,Z,Rx,Ry,Rz[,Re] numbers"
        raise JobError(path, n, f"malformed position {name}: expected {what}, got {','.join(fields)[:60]!r}")
    decimals = tuple(len(f.partition(".")[2]) for f in fields)
    return JobPosition(name, n, postype, tuple(float(f) for f in fields), decimals, tool,  # type: ignore[arg-type]
                       None if pulse else rconf)


def _ints(text: str, n: int, path: Path, what: str) -> tuple[int, ...]:
    fields = [f.strip() for f in text.split(",")]
    if not fields or not all(_INT.match(f) for f in fields):
        raise JobError(path, n, f"malformed {what}: expected integers, got {text.strip()[:40]!r}")
    return tuple(int(f) for f in fields)


def _instructions(texts: list[str], start: int, path: Path
                  ) -> tuple[tuple[tuple[str, ...], ...], dict[str, list[tuple[int, str, int]]]]:
    """Control groups and, per C position, the (group, unit, line) of every move that uses it."""
    groups: dict[int, tuple[str, ...]] = {}
    refs: dict[str, list[tuple[int, str, int]]] = {}
    for i in range(start + 1, len(texts)):
        t, n = texts[i].strip(), i + 1
        m = re.match(r"^///GROUP(\d+)\s+(.+)$", t)
        if m:
            groups[int(m.group(1))] = tuple(u.strip() for u in m.group(2).split(","))
            continue
        if t.startswith("'") or t.startswith("/"):
            continue
        for k, segment in enumerate(_SEGMENT.split(t)):
            tokens = segment.split()
            if not tokens or not _MOVE.match(tokens[0]):
                continue
            cs = [tok for tok in tokens[1:] if _C_REF.match(tok)]
            robots = [u for u in groups.get(k + 1, ("RB1",) if k == 0 else ()) if u.startswith("RB")]
            if len(cs) > len(robots):
                raise JobError(path, n, f"{len(cs)} robot positions in group {k + 1} of this move, but ///GROUP{k + 1} "
                                        f"names {len(robots)} robot(s): {','.join(robots) or 'none'}")
            for c, unit in zip(cs, robots):
                refs.setdefault(c, []).append((k + 1, unit, n))
    order = sorted(groups)
    if order and order != list(range(1, len(order) + 1)):
        raise JobError(path, None, f"control groups {order}; expected ///GROUP1, ///GROUP2, ... in sequence")
    return tuple(groups[g] for g in order) or (("RB1",),), refs


def _assign(positions: list[JobPosition], refs: dict[str, list[tuple[int, str, int]]], groups: tuple[tuple[str, ...], ...],
            path: Path) -> tuple[JobPosition, ...]:
    """Each C position with the robot that moves to it; unused or shared positions are refused."""
    out = []
    seen: set[str] = set()
    for p in positions:
        if p.name in seen:
            raise JobError(path, p.line, f"{p.name} is defined twice")
        seen.add(p.name)
        users = {(g, u) for g, u, _ in refs.get(p.name, [])}
        if not users:
            raise JobError(path, p.line, f"{p.name} is not used by any move instruction; cannot tell its robot")
        if len(users) > 1:
            names = ", ".join(sorted(u for _, u in users))
            raise JobError(path, p.line, f"{p.name} is used by several robots: {names}")
        (g, unit), = users
        out.append(JobPosition(p.name, p.line, p.postype, p.values, p.decimals, p.tool, p.rconf, unit, g))
    missing = sorted(set(refs) - seen)
    if missing:
        raise JobError(path, refs[missing[0]][0][2], f"{missing[0]} is used but not defined in //POS")
    return tuple(out)


def format_values(values: tuple[float, ...] | list[float], decimals: tuple[int, ...]) -> str:
    """The numbers of a position line, each with the digits after the point it was written with."""
    return ",".join(str(int(round(v))) if d == 0 else f"{v:.{d}f}" for v, d in zip(values, decimals))


def write_job(job: Job, replacements: dict[int, str] | None = None) -> bytes:
    """The job's bytes with the lines in ``replacements`` (1-based line -> text without ending) replaced.

    Every other line is the original bytes; a replaced line keeps its original line ending.
    """
    replacements = replacements or {}
    out = []
    for n, raw in enumerate(job.raw_lines, start=1):
        if n in replacements:
            ending = raw[len(raw.rstrip(b"\r\n")):]
            out.append(replacements[n].encode("ascii") + ending)
        else:
            out.append(raw)
    return b"".join(out)


_JOB_NAME = re.compile(r"^[A-Za-z0-9_-]{1,32}$")
_UNIT = re.compile(r"^RB[1-8]$")
#: The joint-speed range of ``VJ=`` [% of each joint's maximum speed] the controller accepts.
VJ_RANGE_PCT = (0.01, 100.0)


def pulse_job(name: str, steps: Sequence[Mapping[str, Sequence[int]]], speed_pct: float, date: datetime) -> bytes:
    """A new INFORM job of joint moves in pulses: one move line per step, every robot of the step in it.

    Each robot is its own control group in the order of its first appearance (``///GROUP1 RB1``,
    ``///GROUP2 RB2``); a step that moves two robots is one coordinated line ``MOVJ C00000 VJ=.. +MOVJ C00001
    VJ=..``, so both reach the step together. Positions are numbered in step order (C00000, C00001, ...), all
    ``///POSTYPE PULSE`` with ``///TOOL 0`` (pulses do not depend on the tool). Lines end in CRLF, as the
    controller writes them. :func:`parse_job` reads the result back to the same pulses.

    Args:
        name: the job name (``//NAME``; the controller wants the file named ``NAME.JBI``), 1-32 of A-Z a-z 0-9 _ -.
        steps: per step, robot unit (``RB1``) -> 6 joint pulses, in the order the job moves through them.
        speed_pct: ``VJ``, the joint speed [% of each joint's maximum], in [0.01, 100].
        date: the ``///DATE`` line.

    Raises:
        JobError: a bad name, speed, unit or pulse count, a step that leaves out a robot of another step, or no
            step (the job would move nothing).
    """
    where = f"{name}.JBI"
    if not _JOB_NAME.match(name):
        raise JobError(where, None, f"job name {name!r} is not 1-32 letters, digits, _ or -; name the file so")
    if not VJ_RANGE_PCT[0] <= speed_pct <= VJ_RANGE_PCT[1]:
        raise JobError(where, None, f"joint speed VJ={speed_pct:g} % outside [{VJ_RANGE_PCT[0]}, {VJ_RANGE_PCT[1]:g}]")
    if not steps:
        raise JobError(where, None, "no positions to move to")
    units: list[str] = []
    for k, step in enumerate(steps):
        for unit, pulses in step.items():
            if not _UNIT.match(unit):
                raise JobError(where, None, f"step {k}: unknown robot unit {unit!r}; expected RB1 .. RB8")
            if len(pulses) != 6 or not all(isinstance(v, int) for v in pulses):
                raise JobError(where, None, f"step {k}, {unit}: expected 6 integer pulses, got {list(pulses)}")
            if unit not in units:
                units.append(unit)
    for k, step in enumerate(steps):  # the k-th '+' segment of a line is group k: a line cannot leave a group out
        if sorted(step) != sorted(units):
            raise JobError(where, None, f"step {k} moves {', '.join(step) or 'nothing'}; every step must move "
                                        f"{', '.join(units)} (a move line's segments are the groups in order)")
    positions, moves, c = [], [], 0
    for step in steps:
        segments = []
        for unit in units:
            if unit in step:
                positions.append(f"C{c:05d}=" + ",".join(str(int(v)) for v in step[unit]))
                segments.append(f"MOVJ C{c:05d} VJ={speed_pct:.2f}")
                c += 1
        moves.append("  +".join(segments))
    lines = ["/JOB", f"//NAME {name}", "//POS", f"///NPOS {c},0,0,0,0,0", "///TOOL 0", "///POSTYPE PULSE",
             "///PULSE", *positions, "//INST", f"///DATE {date:%Y/%m/%d %H:%M}", "///ATTR SC,RW",
             *(f"///GROUP{g} {unit}" for g, unit in enumerate(units, start=1)), "NOP", *moves, "END"]
    return ("\r\n".join(lines) + "\r\n").encode("ascii")

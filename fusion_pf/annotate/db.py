"""SQLite storage of the operators' palm-centre clicks, and the reference derived from them.

Paper 003 §4.1 builds its reference by letting seven operators click the palm
centre of every frame in a web page and taking the mean of their clicks. This
module stores those clicks (one row per operator and frame; a re-click replaces
the row) and computes the per-frame reference (:func:`reference_table`) and the
per-operator agreement (:func:`operator_table`).

Schema
------
``clicks``
    ``operator`` TEXT, ``frame`` INTEGER (index in the recording),
    ``timestamp_ns`` INTEGER (capture time of the frame), ``u``, ``v`` REAL
    (colour pixels; both NULL when the operator marked the palm "not visible"),
    ``visible`` INTEGER (1 clicked, 0 not visible), ``clicked_ns`` INTEGER (server
    wall-clock time of the click, ``time.time_ns()``). Primary key
    ``(operator, frame)``.
``meta``
    ``key``/``value`` text pairs: ``schema_version``, ``recording`` (file name),
    ``recording_sha256`` (SHA-256 of the recording file, :func:`recording_sha256`),
    ``n_frames``, ``width``, ``height``. A database made for one recording
    refuses to annotate any other file (another content hash), whatever its
    shape; a database written before the hash was stored adopts the hash of the
    first recording it is opened with, provided every stored click's frame and
    timestamp match that recording.

Tracker outputs belong to a recording too: :func:`check_reference_matches`
tells ``score --reference DB`` whether a tracked file's frames (and, when its
metadata carries it, the source recording's hash) are those of the annotated
recording.

WAL and checkpoints
-------------------
In WAL mode committed clicks first live in ``<db>-wal``; SQLite copies them into
the main file at checkpoints. :meth:`AnnotationDB.close` (server shutdown,
Ctrl-C) and :func:`checkpoint` (run by ``annotations export`` before reading)
checkpoint with ``TRUNCATE``, so after a clean stop or an export the ``.sqlite``
file alone holds every click and can be copied by itself. After a kill -9 the
clicks are still safe in the ``-wal`` file (keep it next to the database); the
next open or export checkpoints them.

Durability
----------
The database runs in WAL mode with ``synchronous=FULL`` and every click is its
own transaction, committed before the HTTP response acknowledges it. In WAL
mode a commit appends the transaction to the ``-wal`` file; with
``synchronous=NORMAL`` that append is not fsynced, which already survives the
*process* being killed (SIGKILL: the data sits in the OS page cache and the next
open replays the WAL) but may lose the last transactions on power loss or an OS
crash. ``synchronous=FULL`` fsyncs the WAL on every commit, so an acknowledged
click also survives power loss. Clicks arrive at human rates (a few per second
per operator), so the fsync per commit costs nothing that matters; the load
test measures it.
"""

from __future__ import annotations

import csv
import hashlib
import math
import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from fusion_pf.errors import InputError, RecordingError

#: Version of the schema written in ``meta``.
SCHEMA_VERSION = 1

#: Longest operator name accepted, in characters.
MAX_OPERATOR_LEN = 64

_SCHEMA = """
CREATE TABLE IF NOT EXISTS clicks (
    operator     TEXT    NOT NULL,
    frame        INTEGER NOT NULL CHECK (frame >= 0),
    timestamp_ns INTEGER NOT NULL CHECK (timestamp_ns >= 0),
    u            REAL,
    v            REAL,
    visible      INTEGER NOT NULL CHECK (visible IN (0, 1)),
    clicked_ns   INTEGER NOT NULL,
    PRIMARY KEY (operator, frame),
    CHECK ((visible = 1 AND u IS NOT NULL AND v IS NOT NULL)
        OR (visible = 0 AND u IS NULL AND v IS NULL))
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS clicks_by_frame ON clicks (frame);
CREATE TABLE IF NOT EXISTS meta (
    key   TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""

_COLUMNS = "operator, frame, timestamp_ns, u, v, visible, clicked_ns"


def validate_operator(name: object) -> str:
    """Return ``name`` stripped, or raise when it is not a usable operator name.

    Parameters
    ----------
    name : object
        The name as received.

    Returns
    -------
    str
        The stripped name: 1 to :data:`MAX_OPERATOR_LEN` printable characters.

    Raises
    ------
    InputError
        When ``name`` is not a string, is empty, too long or holds control characters.
    """
    if not isinstance(name, str):
        raise InputError(f"operator must be a string, got {type(name).__name__}")
    name = name.strip()
    if not name:
        raise InputError("operator must not be empty")
    if len(name) > MAX_OPERATOR_LEN:
        raise InputError(f"operator must be at most {MAX_OPERATOR_LEN} characters, got {len(name)}")
    if not name.isprintable():
        raise InputError(f"operator must be printable text, got {name!r}")
    return name


@dataclass(frozen=True)
class Click:
    """One stored annotation: an operator's palm centre (or "not visible") on one frame.

    Attributes
    ----------
    operator : str
        Operator name.
    frame : int
        Frame index in the recording.
    timestamp_ns : int
        Capture time of the frame.
    u, v : float or None
        Palm centre in colour pixels; None when ``visible`` is False.
    visible : bool
        False when the operator marked the palm "not visible".
    clicked_ns : int
        Server wall-clock time of the click (``time.time_ns()``).
    """

    operator: str
    frame: int
    timestamp_ns: int
    u: float | None
    v: float | None
    visible: bool
    clicked_ns: int

    @classmethod
    def from_row(cls, row: tuple) -> "Click":
        """Build a click from a ``SELECT operator, frame, ..., clicked_ns`` row."""
        operator, frame, timestamp_ns, u, v, visible, clicked_ns = row
        return cls(operator, int(frame), int(timestamp_ns), u, v, bool(visible), int(clicked_ns))

    @property
    def uv(self) -> tuple[float, float]:
        """``(u, v)`` of a visible click (the table's CHECK gives visible clicks both numbers)."""
        assert self.u is not None and self.v is not None, "a visible click has a position"
        return self.u, self.v

    def to_json(self) -> dict:
        """The click as a JSON-ready dict (the keys of the attributes)."""
        return {
            "operator": self.operator,
            "frame": self.frame,
            "timestamp_ns": self.timestamp_ns,
            "u": self.u,
            "v": self.v,
            "visible": self.visible,
            "clicked_ns": self.clicked_ns,
        }


def recording_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a recording file's bytes: the identity of the recording.

    Raises
    ------
    RecordingError
        When the file cannot be read.
    """
    try:
        with open(path, "rb") as fh:
            return hashlib.file_digest(fh, "sha256").hexdigest()
    except OSError as exc:
        raise RecordingError(f"cannot read {path}: {exc.strerror or exc}") from None


def _check_db_path(path: Path) -> None:
    if path.is_dir():
        raise InputError(f"annotation database {path} is a directory; expected an SQLite file name")
    if not path.parent.is_dir():
        raise InputError(f"the folder of the annotation database {path} does not exist: {path.parent}")


def _connect(path: Path, *, readonly: bool = False) -> sqlite3.Connection:
    _check_db_path(path)
    try:
        if readonly:
            if not path.is_file():
                raise RecordingError(f"no such annotation database: {path}")
            conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=10.0)
        else:
            # one connection per thread; close() may run in another thread (the main one, after Ctrl-C)
            conn = sqlite3.connect(path, timeout=10.0, isolation_level=None, check_same_thread=False)
    except sqlite3.Error as exc:
        raise RecordingError(f"cannot open the annotation database {path}: {exc}") from None
    try:
        conn.execute("PRAGMA busy_timeout = 10000")
        if not readonly:
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise RecordingError(f"{path}: cannot switch SQLite to WAL mode (got {mode!r})")
            conn.execute("PRAGMA synchronous = FULL")
        conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise RecordingError(f"{path} is not an annotation database: {exc}") from None
    return conn


class AnnotationDB:
    """The click database of one recording, safe to use from many threads.

    Every thread gets its own SQLite connection; writes are serialised by
    SQLite (``BEGIN IMMEDIATE``) and committed before the methods return.

    Parameters
    ----------
    path : str or Path
        SQLite file, created when missing (its folder must exist).
    recording : str
        Name of the annotated recording (stored in ``meta`` when new).
    sha256 : str, optional
        :func:`recording_sha256` of the recording; a database holding another
        hash is refused.
    timestamps : sequence of int, optional
        Frame timestamps of the recording; a database without a stored hash
        adopts ``sha256`` only when every click's frame has this timestamp.
    n_frames : int
        Frames in the recording; clicks must have ``0 <= frame < n_frames``.
    width, height : int
        Colour image size; clicks must lie inside it (see :meth:`set_click`).

    Raises
    ------
    RecordingError
        When the file is not an SQLite database, or was made for another
        recording (another content hash, frame count or image size).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        recording: str,
        n_frames: int,
        width: int,
        height: int,
        sha256: str | None = None,
        timestamps: "list[int] | None" = None,
    ) -> None:
        self.path = Path(path)
        self.n_frames = int(n_frames)
        self.width = int(width)
        self.height = int(height)
        self._local = threading.local()
        self._all: list[sqlite3.Connection] = []
        self._all_lock = threading.Lock()
        conn = self._conn()
        try:
            conn.executescript(_SCHEMA)
        except sqlite3.Error as exc:
            self.close()
            raise RecordingError(f"{self.path} cannot be used as an annotation database: {exc}") from None
        wanted = {
            "schema_version": str(SCHEMA_VERSION),
            "recording": recording,
            "n_frames": str(self.n_frames),
            "width": str(self.width),
            "height": str(self.height),
        }
        conn.execute("BEGIN IMMEDIATE")
        try:
            have = dict(conn.execute("SELECT key, value FROM meta").fetchall())
            for key in ("n_frames", "width", "height"):
                if key in have and have[key] != wanted[key]:
                    raise RecordingError(
                        f"{self.path} holds annotations of {have.get('recording', '?')!r} with "
                        f"{key} = {have[key]}, but this recording has {key} = {wanted[key]}"
                    )
            if sha256 is not None:
                stored = have.get("recording_sha256")
                if stored is not None and stored != sha256:
                    raise RecordingError(
                        f"{self.path} holds annotations of another recording ({have.get('recording', '?')!r}, "
                        f"SHA-256 {stored[:16]}...), not of {recording!r} (SHA-256 {sha256[:16]}...)"
                    )
                if stored is None and have:
                    self._check_clicks_fit(conn, timestamps, recording)
                wanted["recording_sha256"] = sha256
            conn.executemany("INSERT OR IGNORE INTO meta (key, value) VALUES (?, ?)", sorted(wanted.items()))
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            self.close()
            raise

    def _check_clicks_fit(self, conn: sqlite3.Connection, timestamps: "list[int] | None", recording: str) -> None:
        """Refuse to adopt a hash when a stored click's frame has another timestamp in this recording."""
        rows = conn.execute("SELECT DISTINCT frame, timestamp_ns FROM clicks").fetchall()
        if rows and timestamps is None:
            raise RecordingError(
                f"{self.path} has no recording hash; cannot tell whether its clicks are of {recording!r}"
            )
        for frame, t in rows:
            if not (0 <= frame < len(timestamps or ()) and int(timestamps[frame]) == t):  # type: ignore[index]
                raise RecordingError(
                    f"{self.path} holds a click on frame {frame} at t={t} ns, which is not a frame of {recording!r}; "
                    "it was made for another recording"
                )

    def _conn(self) -> sqlite3.Connection:
        conn = getattr(self._local, "conn", None)
        if conn is None:
            conn = _connect(self.path)
            self._local.conn = conn
            with self._all_lock:
                self._all.append(conn)
        return conn

    def close(self) -> None:
        """Checkpoint the WAL into the database file, then close every thread's connection.

        Call when no request runs any more (server shutdown, Ctrl-C).
        """
        with self._all_lock:
            conns, self._all = self._all, []
        try:
            if conns:
                conns[0].execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
        except sqlite3.Error:
            pass  # a reader still holds the WAL; the clicks stay safe in it
        finally:
            for conn in conns:
                conn.close()
            self._local = threading.local()

    def check_click(self, frame: object, u: object, v: object) -> tuple[int, float | None, float | None]:
        """Validate a click's frame index and position.

        Parameters
        ----------
        frame : object
            Frame index, an int in ``[0, n_frames)``.
        u, v : object
            Position in colour pixels, both numbers, or both None for "not visible".
            Pixel centres are at integers, so the image covers
            ``-0.5 <= u <= width - 0.5`` and ``-0.5 <= v <= height - 0.5``.

        Returns
        -------
        tuple
            ``(frame, u, v)`` as int and floats (or Nones).

        Raises
        ------
        InputError
            Naming the bad value and the accepted range.
        """
        if isinstance(frame, bool) or not isinstance(frame, int):
            raise InputError(f"frame must be an integer index, got {str(frame)[:40]!r}")
        if not 0 <= frame < self.n_frames:
            shown = str(frame) if len(str(frame)) <= 20 else f"a {len(str(abs(frame)))}-digit integer"
            raise InputError(f"frame {shown} is out of range [0, {self.n_frames})")
        if u is None and v is None:
            return frame, None, None
        out = []
        for name, value, size in (("u", u, self.width), ("v", v, self.height)):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InputError(f"{name} must be a number (or u and v both null), got {value!r}")
            try:
                value = float(value)
            except OverflowError:
                raise InputError(
                    f"{name} = a {len(str(abs(value)))}-digit integer is outside the image: expected "
                    f"-0.5 <= {name} <= {size - 0.5}"
                ) from None
            if not math.isfinite(value) or not -0.5 <= value <= size - 0.5:
                raise InputError(f"{name} = {value} is outside the image: expected -0.5 <= {name} <= {size - 0.5}")
            out.append(value)
        return frame, out[0], out[1]

    def set_click(self, operator: str, frame: int, timestamp_ns: int, u: float | None, v: float | None) -> Click:
        """Store (or replace) ``operator``'s click on ``frame`` and commit it.

        Parameters
        ----------
        operator : str
            Operator name (validated by :func:`validate_operator`).
        frame : int
            Frame index.
        timestamp_ns : int
            Capture time of the frame.
        u, v : float or None
            Palm centre, or both None for "not visible" (validated by :meth:`check_click`).

        Returns
        -------
        Click
            The stored row; it is committed (durable) when this returns.
        """
        operator = validate_operator(operator)
        frame, u, v = self.check_click(frame, u, v)
        if isinstance(timestamp_ns, bool) or not isinstance(timestamp_ns, int) or timestamp_ns < 0:
            raise InputError(f"timestamp_ns must be a non-negative int, got {timestamp_ns!r}")
        click = Click(operator, frame, timestamp_ns, u, v, u is not None, time.time_ns())
        conn = self._conn()
        conn.execute("BEGIN IMMEDIATE")
        try:
            conn.execute(
                f"INSERT INTO clicks ({_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?) "
                "ON CONFLICT (operator, frame) DO UPDATE SET timestamp_ns = excluded.timestamp_ns, "
                "u = excluded.u, v = excluded.v, visible = excluded.visible, "
                "clicked_ns = excluded.clicked_ns",
                (operator, frame, timestamp_ns, u, v, int(click.visible), click.clicked_ns),
            )
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        return click

    def operator_clicks(self, operator: str) -> list[Click]:
        """Every click of ``operator``, by frame."""
        rows = (
            self._conn()
            .execute(f"SELECT {_COLUMNS} FROM clicks WHERE operator = ? ORDER BY frame", (operator,))
            .fetchall()
        )
        return [Click.from_row(r) for r in rows]

    def count_clicks(self, operator: str) -> int:
        """Number of frames ``operator`` has done (clicked or marked "not visible")."""
        return self._conn().execute("SELECT count(*) FROM clicks WHERE operator = ?", (operator,)).fetchone()[0]

    def frame_clicks(self, frame: int) -> list[Click]:
        """Every operator's click on ``frame``, by operator name."""
        rows = (
            self._conn()
            .execute(f"SELECT {_COLUMNS} FROM clicks WHERE frame = ? ORDER BY operator", (frame,))
            .fetchall()
        )
        return [Click.from_row(r) for r in rows]


def checkpoint(db_path: str | Path) -> None:
    """Copy the clicks still in ``<db>-wal`` into the database file (``wal_checkpoint(TRUNCATE)``).

    Nothing to do when there is no ``-wal`` file. A busy database (a server
    still writing) is checkpointed as far as possible.

    Raises
    ------
    RecordingError
        When the file is missing or is not an annotation database.
    """
    path = Path(db_path)
    _check_db_path(path)
    if not path.is_file():
        raise RecordingError(f"no such annotation database: {path}")
    if not path.with_name(path.name + "-wal").exists():
        return
    conn = _connect(path)
    try:
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
    except sqlite3.Error as exc:
        raise RecordingError(f"cannot checkpoint {path}: {exc}") from None
    finally:
        conn.close()


def read_meta(db_path: str | Path) -> dict[str, str]:
    """The ``meta`` table of an annotation database (read-only)."""
    path = Path(db_path)
    conn = _connect(path, readonly=True)
    try:
        return dict(conn.execute("SELECT key, value FROM meta").fetchall())
    except sqlite3.DatabaseError as exc:
        raise RecordingError(f"{path} is not an annotation database: {exc}") from None
    finally:
        conn.close()


def check_reference_matches(
    db_path: str | Path,
    frames: "list[int]",
    timestamps_ns: "list[int]",
    *,
    source_sha256: str | None = None,
    what: str = "the tracked file",
) -> None:
    """Raise unless ``what`` (a tracker output) belongs to the recording the database annotates.

    Two checks, each one enough to refuse a mismatched pair: the recording hash
    (``source_sha256``, from the tracked file's ``fusion_pf.recording`` metadata
    key ``source_sha256``, against the database's ``recording_sha256``; skipped
    when either is absent), and every annotated frame's timestamp (the
    tracked file's frame ``f`` must have the timestamp the operators' clicks on
    frame ``f`` carry; frames the tracked file lacks are not compared).

    Parameters
    ----------
    db_path : str or Path
        The annotation database (``score --reference DB``).
    frames, timestamps_ns : sequence of int, shape (n,)
        Frame indices and timestamps of the tracked file's rows.
    source_sha256 : str, optional
        The hash of the recording the tracked file was made from.
    what : str
        Names the tracked file in the message.

    Raises
    ------
    RecordingError
        Naming the mismatch.
    """
    meta = read_meta(db_path)
    stored = meta.get("recording_sha256")
    if stored is not None and source_sha256 is not None and stored != source_sha256:
        raise RecordingError(
            f"{what} was made from another recording (SHA-256 {source_sha256[:16]}...) than the one "
            f"{db_path} annotates ({meta.get('recording', '?')!r}, SHA-256 {stored[:16]}...)"
        )
    tracked = dict(zip((int(f) for f in frames), (int(t) for t in timestamps_ns)))
    clicks = read_clicks(db_path)
    compared = 0
    for c in clicks:
        t = tracked.get(c.frame)
        if t is None:
            continue
        if t != c.timestamp_ns:
            raise RecordingError(
                f"{what} is not of the recording {db_path} annotates ({meta.get('recording', '?')!r}): its frame "
                f"{c.frame} is at t={t} ns, the annotated frame {c.frame} at t={c.timestamp_ns} ns"
            )
        compared += 1
    if compared == 0 and tracked and clicks:
        raise RecordingError(
            f"{what} has none of the frames annotated in {db_path}; they cannot be of the same recording"
        )


def read_clicks(db_path: str | Path) -> list[Click]:
    """Every click stored in ``db_path``, by frame then operator (read-only access).

    Raises
    ------
    RecordingError
        When the file is missing or is not an annotation database.
    """
    path = Path(db_path)
    conn = _connect(path, readonly=True)
    try:
        rows = conn.execute(f"SELECT {_COLUMNS} FROM clicks ORDER BY frame, operator").fetchall()
    except sqlite3.DatabaseError as exc:
        raise RecordingError(f"{path} is not an annotation database: {exc}") from None
    finally:
        conn.close()
    return [Click.from_row(r) for r in rows]


def summarize_frame(clicks: list[Click]) -> dict:
    """Reference of one frame from its clicks (the mean of paper 003 §4.1).

    Parameters
    ----------
    clicks : list of Click
        The clicks of one frame (any number of operators).

    Returns
    -------
    dict
        ``n_operators`` (operators who did the frame, clicked or "not visible"),
        ``n_not_visible``, ``mean_u``, ``mean_v`` (mean of the visible clicks,
        None when nobody saw the palm) and ``spread_px`` (mean Euclidean
        distance of the visible clicks to that mean; 0.0 for one click, None when
        nobody saw the palm).
    """
    seen = [c.uv for c in clicks if c.visible]
    out = {"n_operators": len(clicks), "n_not_visible": len(clicks) - len(seen)}
    if not seen:
        return {**out, "mean_u": None, "mean_v": None, "spread_px": None}
    mu = math.fsum(u for u, _ in seen) / len(seen)
    mv = math.fsum(v for _, v in seen) / len(seen)
    spread = math.fsum(math.hypot(u - mu, v - mv) for u, v in seen) / len(seen)
    return {**out, "mean_u": mu, "mean_v": mv, "spread_px": spread}


def _by_frame(clicks: list[Click]) -> dict[int, list[Click]]:
    frames: dict[int, list[Click]] = {}
    for c in clicks:
        frames.setdefault(c.frame, []).append(c)
    return frames


def reference_table(db_path: str | Path) -> list[dict]:
    """The per-frame reference of an annotation database, for the scorer.

    Parameters
    ----------
    db_path : str or Path
        SQLite file written by ``fusion-pf annotate``.

    Returns
    -------
    list of dict
        One dict per frame that at least one operator did, by frame index, with
        keys ``frame``, ``timestamp_ns``, ``n_operators``, ``n_not_visible``,
        ``mean_u``, ``mean_v``, ``spread_px`` (see :func:`summarize_frame`).
        Frames nobody annotated are absent.

    Raises
    ------
    RecordingError
        When the file is missing or is not an annotation database.
    """
    table = []
    for frame, clicks in sorted(_by_frame(read_clicks(db_path)).items()):
        table.append({"frame": frame, "timestamp_ns": clicks[0].timestamp_ns, **summarize_frame(clicks)})
    return table


def operator_table(db_path: str | Path) -> list[dict]:
    """Agreement of every operator with the others.

    For each frame where the operator clicked and at least one other operator
    clicked too, the distance from the operator's click to the mean of the
    *other* operators' clicks (leave-one-out mean) is taken; these distances are
    averaged over the frames.

    Parameters
    ----------
    db_path : str or Path
        SQLite file written by ``fusion-pf annotate``.

    Returns
    -------
    list of dict
        One dict per operator, by name, with keys ``operator``, ``n_frames``
        (frames done), ``n_not_visible``, ``n_compared`` (frames entering the
        mean), ``mean_dist_to_others_px`` and ``max_dist_to_others_px`` (None
        when ``n_compared`` is 0), and ``n_visibility_disagreements`` (frames the
        operator marked "not visible" while another operator clicked, or
        clicked while another marked "not visible").

    Raises
    ------
    RecordingError
        When the file is missing or is not an annotation database.
    """
    stats: dict[str, dict] = {}
    for clicks in _by_frame(read_clicks(db_path)).values():
        seen = [c for c in clicks if c.visible]
        n_hidden = len(clicks) - len(seen)
        for c in clicks:
            s = stats.setdefault(c.operator, {"n_frames": 0, "n_not_visible": 0, "dists": [], "disagree": 0})
            s["n_frames"] += 1
            if not c.visible:
                s["n_not_visible"] += 1
                s["disagree"] += bool(seen)
                continue
            s["disagree"] += n_hidden > 0
            others = [o.uv for o in seen if o.operator != c.operator]
            if others:
                mu = math.fsum(u for u, _ in others) / len(others)
                mv = math.fsum(v for _, v in others) / len(others)
                cu, cv = c.uv
                s["dists"].append(math.hypot(cu - mu, cv - mv))
    table = []
    for operator, s in sorted(stats.items()):
        d = s["dists"]
        table.append(
            {
                "operator": operator,
                "n_frames": s["n_frames"],
                "n_not_visible": s["n_not_visible"],
                "n_compared": len(d),
                "mean_dist_to_others_px": math.fsum(d) / len(d) if d else None,
                "max_dist_to_others_px": max(d) if d else None,
                "n_visibility_disagreements": s["disagree"],
            }
        )
    return table


#: Column order of :func:`write_reference_csv`.
REFERENCE_COLUMNS = ("frame", "timestamp_ns", "n_operators", "n_not_visible", "mean_u", "mean_v", "spread_px")
#: Column order of :func:`write_operators_csv`.
OPERATOR_COLUMNS = (
    "operator",
    "n_frames",
    "n_not_visible",
    "n_compared",
    "mean_dist_to_others_px",
    "max_dist_to_others_px",
    "n_visibility_disagreements",
)


#: First characters that make a spreadsheet read a cell as a formula (OWASP "CSV injection").
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.3f}"
    if isinstance(value, str) and value.startswith(_FORMULA_START):
        return "'" + value  # shown as text, never run as a formula
    return str(value)


def _write_csv(rows: list[dict], columns: tuple[str, ...], out: Path) -> None:
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(columns)
        for row in rows:
            writer.writerow([_cell(row[c]) for c in columns])
    os.replace(tmp, out)


def write_reference_csv(db_path: str | Path, out: str | Path) -> int:
    """Write :func:`reference_table` as CSV (floats with 3 decimals, empty cell = None).

    Returns
    -------
    int
        Number of frame rows written.
    """
    rows = reference_table(db_path)
    _write_csv(rows, REFERENCE_COLUMNS, Path(out))
    return len(rows)


def write_operators_csv(db_path: str | Path, out: str | Path) -> int:
    """Write :func:`operator_table` as CSV (floats with 3 decimals, empty cell = None).

    Returns
    -------
    int
        Number of operator rows written.
    """
    rows = operator_table(db_path)
    _write_csv(rows, OPERATOR_COLUMNS, Path(out))
    return len(rows)

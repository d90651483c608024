"""Read what a truncated or index-damaged bag still holds: the complete messages before the cut.

A recorder killed mid-write (power cut, full disk, ``kill -9``) leaves an MCAP file without its
summary and footer, and often a bag folder without ``metadata.yaml``; rosbags refuses such files
("File end magic is invalid"). `SalvagedBag` scans the MCAP records from the start instead and
stops at the first incomplete one (an incomplete last chunk is decompressed as far as it goes);
for SQLite (``.db3``) it reads rows in insertion order until the database gives out (a cut-off file
is first copied to a temporary file whose header is made to match its length: SQLite refuses a file
shorter than its header says). It mirrors the part of rosbags' ``AnyReader`` the loaders use:
``connections``, ``messages()``, ``deserialize()``.
"""

from __future__ import annotations

import io
import logging
import shutil
import sqlite3
import struct
import sys
import tempfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

log = logging.getLogger(__name__)

MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_DATA_END, _OP_FOOTER = 0x03, 0x04, 0x05, 0x06, 0x0F, 0x02


@dataclass(frozen=True)
class SalvageConnection:
    """The fields of a rosbags ``Connection`` the loaders read."""

    id: int
    topic: str
    msgtype: str
    msgcount: int
    path: str


class _Truncated(Exception):
    pass


def _read(bio: BinaryIO, n: int) -> bytes:
    data = bio.read(n)
    if len(data) != n:
        raise _Truncated
    return data


def _string(buf: io.BytesIO) -> str:
    (n,) = struct.unpack("<I", _read(buf, 4))
    return _read(buf, n).decode("utf-8", "replace")


def _partial_decompress(data: bytes, compression: str) -> bytes:
    """As much of a cut-off compressed chunk as decodes (b'' when nothing does)."""
    try:
        if compression == "zstd":
            if sys.version_info >= (3, 14):
                from compression import zstd  # type: ignore[import-not-found, unused-ignore]
            else:
                from backports import zstd  # type: ignore[import-not-found, unused-ignore]
            return bytes(zstd.ZstdDecompressor().decompress(data))
        if compression == "lz4":
            from lz4.frame import LZ4FrameDecompressor  # type: ignore[import-untyped, unused-ignore]

            return bytes(LZ4FrameDecompressor().decompress(data))
    except Exception:  # a damaged frame: whatever came out before it is lost too
        return b""
    return b""


def _full_decompress(data: bytes, compression: str, size: int) -> bytes:
    if compression == "":
        return data
    out = _partial_decompress(data, compression)
    if len(out) != size:
        raise _Truncated
    return out


class _McapScan:
    """One pass over an MCAP file's records (chunks opened), tolerant of a cut-off end."""

    def __init__(self, path: Path):
        self.path = path
        self.size = path.stat().st_size
        self.complete_bytes = 0
        self.truncated = False
        self.schemas: dict[int, str] = {}
        self.channels: dict[int, tuple[str, int]] = {}

    def records(self) -> Iterator[tuple[int, bytes]]:
        """(opcode, content) of every complete record, chunk contents included, in file order."""
        with self.path.open("rb") as bio:
            if bio.read(8) != MCAP_MAGIC:
                raise ValueError(f"{self.path} is not an MCAP file (bad magic)")
            while True:
                start = bio.tell()
                head = bio.read(9)
                if not head:
                    return
                try:
                    if len(head) != 9:
                        raise _Truncated
                    op, length = head[0], struct.unpack("<Q", head[1:])[0]
                    if op == _OP_CHUNK:
                        yield from self._chunk(bio, length)
                    else:
                        content = _read(bio, length)
                        if op in (_OP_DATA_END, _OP_FOOTER):
                            self.complete_bytes = self.size
                            return
                        yield op, content
                except _Truncated:
                    self.truncated = True
                    self.complete_bytes = start
                    return
                self.complete_bytes = bio.tell()

    def _chunk(self, bio: BinaryIO, length: int) -> Iterator[tuple[int, bytes]]:
        start = bio.tell()
        head = bio.read(28)
        if len(head) != 28:
            raise _Truncated
        _t0, _t1, usize, _crc = struct.unpack("<QQQI", head)
        (clen,) = struct.unpack("<I", _read(bio, 4))
        compression = _read(bio, clen).decode()
        (rlen,) = struct.unpack("<Q", _read(bio, 8))
        data = bio.read(rlen)
        complete = len(data) == rlen and bio.tell() - start <= length
        if complete:
            bio.seek(start + length)
            inner = _full_decompress(data, compression, usize)
        else:
            inner = data if compression == "" else _partial_decompress(data, compression)
        buf = io.BytesIO(inner)
        while True:
            head = buf.read(9)
            if len(head) < 9:
                break
            op, n = head[0], struct.unpack("<Q", head[1:])[0]
            content = buf.read(n)
            if len(content) != n:
                break
            yield op, content
        if not complete:
            raise _Truncated

    def parse(self, op: int, content: bytes) -> tuple[int, int, bytes] | None:
        """Register schemas/channels; (channel id, log time, payload) for a message record."""
        if op == _OP_MESSAGE:
            cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", content)
            return cid, log_time, content[22:]
        buf = io.BytesIO(content)
        try:
            if op == _OP_SCHEMA:
                (sid,) = struct.unpack("<H", _read(buf, 2))
                self.schemas[sid] = _string(buf)
            elif op == _OP_CHANNEL:
                cid, sid = struct.unpack("<HH", _read(buf, 4))
                self.channels[cid] = (_string(buf), sid)
        except _Truncated:
            pass
        return None


class SalvagedBag:
    """The complete messages of truncated / damaged bag storage files (MCAP or SQLite)."""

    def __init__(self, paths: Iterable[str | Path], typestore: Any):
        self.paths = [Path(p) for p in paths]
        self.typestore = typestore
        self.connections: list[SalvageConnection] = []
        self.truncated = False
        #: Where each file stopped: "name: N of M bytes readable" lines.
        self.damage: list[str] = []
        self._ids: dict[tuple[str, int], int] = {}
        self._tmp: tempfile.TemporaryDirectory | None = None
        self._sqlite: dict[Path, Path] = {}  # a cut-off .db3 -> its readable temporary copy
        self._scan_all()

    # context manager and AnyReader look-alike -------------------------------------------------
    def open(self) -> None:
        """Nothing to open: files are opened per pass."""

    def close(self) -> None:
        """Remove temporary copies (files themselves are closed after each pass)."""
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
            self._sqlite.clear()

    def __enter__(self) -> SalvagedBag:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.typestore.deserialize_cdr(raw, msgtype)

    # scanning -----------------------------------------------------------------------------------
    def _scan_all(self) -> None:
        counts: dict[int, int] = {}
        meta: dict[int, tuple[str, str, str]] = {}
        for path in self.paths:
            for conn_key, (topic, msgtype), _t, _raw in self._iter_file(path, payload=False):
                cid = self._conn_id(str(path), conn_key)
                counts[cid] = counts.get(cid, 0) + 1
                meta[cid] = (topic, msgtype, str(path))
        self.connections = [SalvageConnection(cid, *meta[cid][:2], counts[cid], meta[cid][2])
                            for cid in sorted(meta)]

    def _conn_id(self, path: str, key: int) -> int:
        return self._ids.setdefault((path, key), len(self._ids) + 1)

    def _iter_file(self, path: Path, payload: bool) -> Iterator[tuple[int, tuple[str, str], int, bytes]]:
        if path.suffix == ".db3":
            yield from self._iter_sqlite(path)
            return
        scan = _McapScan(path)
        for op, content in scan.records():
            msg = scan.parse(op, content)
            if msg is None:
                continue
            cid, log_time, data = msg
            if cid not in scan.channels:
                continue
            topic, sid = scan.channels[cid]
            yield cid, (topic, scan.schemas.get(sid, "")), log_time, data if payload else b""
        self._note(path, scan.truncated, scan.complete_bytes, scan.size)

    def _readable_sqlite(self, path: Path) -> Path:
        """`path`, or a temporary copy cut to whole pages whose header page count matches its length."""
        if path in self._sqlite:
            return self._sqlite[path]
        try:
            with sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True) as db:
                db.execute("SELECT count(*) FROM topics").fetchone()
            self._sqlite[path] = path
            return path
        except sqlite3.Error:
            pass
        with path.open("rb") as fh:
            header = fh.read(100)
        if len(header) < 100 or not header.startswith(b"SQLite format 3\x00"):
            self._sqlite[path] = path
            return path
        page = struct.unpack(">H", header[16:18])[0]
        page = 65536 if page == 1 else page
        pages = path.stat().st_size // page
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="scene_recon_salvage_")
        copy = Path(self._tmp.name) / f"{len(self._sqlite)}_{path.name}"
        shutil.copyfile(path, copy)
        with copy.open("r+b") as fh:
            fh.truncate(pages * page)
            fh.seek(28)
            fh.write(struct.pack(">I", pages))
        self._sqlite[path] = copy
        return copy

    def _iter_sqlite(self, path: Path) -> Iterator[tuple[int, tuple[str, str], int, bytes]]:
        size = path.stat().st_size
        readable = self._readable_sqlite(path)
        try:
            db = sqlite3.connect(f"file:{readable}?mode=ro&immutable=1", uri=True)
        except sqlite3.Error:
            self._note(path, True, 0, size)
            return
        damaged = False
        try:
            topics = {int(i): (str(n), str(t)) for i, n, t in db.execute("SELECT id, name, type FROM topics")}
            for tid, stamp, data in db.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY rowid"):
                if int(tid) in topics:
                    yield int(tid), topics[int(tid)], int(stamp), bytes(data)
        except sqlite3.Error:
            damaged = True
        finally:
            db.close()
        self._note(path, damaged or readable != path, -1, size)

    def _note(self, path: Path, truncated: bool, complete: int, size: int) -> None:
        if not truncated:
            return
        self.truncated = True
        where = f"{complete} of {size} bytes readable" if complete >= 0 else "database damaged"
        line = f"{path.name}: {where}"
        if line not in self.damage:
            self.damage.append(line)

    def messages(self, connections: Iterable[SalvageConnection] | None = None
                 ) -> Iterator[tuple[SalvageConnection, int, bytes]]:
        """(connection, log time, raw CDR) of every complete message, in file order."""
        wanted = {c.id: c for c in (connections if connections is not None else self.connections)}
        for path in self.paths:
            for key, _types, log_time, data in self._iter_file(path, payload=True):
                conn = wanted.get(self._ids.get((str(path), key), -1))
                if conn is not None:
                    yield conn, log_time, data


def storage_files(path: Path) -> list[Path]:
    """The .mcap / .db3 files of a bag path (the file itself, or those in the folder, sorted)."""
    if path.is_file():
        return [path]
    return sorted(p for p in path.iterdir() if p.suffix in (".mcap", ".db3") and p.is_file())

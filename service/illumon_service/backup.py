"""``illumon backup DEST`` and ``illumon restore SRC``: the database and the data directory, online.

A backup is a folder (mode 0700: it holds the admin token and the cameras' token hashes)::

    DEST/manifest.json      format, time, database kind, row counts, files, files missing at the snapshot, and
                            SQLite's integrity check of the snapshot
    DEST/illumon.sqlite3    SQLite: a consistent snapshot by the online backup API (``sqlite3.Connection.backup``)
    DEST/database.pgdump    PostgreSQL: ``pg_dump --format=custom`` (one consistent transaction)
    DEST/data/              the data directory: models, thumbnails and reference frames, kept images, admin token

It is taken while the service runs: frames keep being written, and a frame acknowledged before the snapshot is in
it. The files are copied before and again after the database snapshot, so that every file the snapshot refers to
is there (a thumbnail pruned between the two is forgotten in the copy, and counted in the manifest). The backup is
written to ``DEST.partial`` and renamed to ``DEST`` when complete: a folder named ``DEST`` is always a whole backup.

``restore`` fills an empty data directory (and, for PostgreSQL, a database without illumon data; ``--force``
replaces what is there) and brings the schema up to this version; file paths in the database are relative to the
data directory (:mod:`.datafiles`), so the restored copy refers to its own files only. Stop the service before
restoring into its data directory.
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from sqlalchemy.engine import Engine, make_url

from . import crud
from .settings import Settings
from .storage import make_engine

__all__ = ["BackupError", "backup", "restore", "FORMAT", "one_line_errors"]

FORMAT = 1
"""Version of the backup layout (``manifest.json``'s ``format``)."""

SQLITE_NAME = "illumon.sqlite3"
PG_NAME = "database.pgdump"
_SKIP_DIRS = {"metrics"}
"""Data-directory folders not backed up (per-process figures, emptied at every start)."""


class BackupError(ValueError):
    """A backup or restore that cannot be done; the CLI prints its message on one line and exits with status 2."""


@contextmanager
def one_line_errors(what: str) -> Iterator[None]:
    """Turn the file-system and database errors of an operations command (a folder not writable, a database that
    cannot be reached or read) into a :class:`BackupError` of one line, which the CLI prints and exits 2 with."""
    from sqlalchemy.exc import SQLAlchemyError

    try:
        yield
    except BackupError:
        raise
    except (OSError, sqlite3.Error, SQLAlchemyError) as exc:
        text = str(getattr(exc, "orig", None) or exc).strip().splitlines()
        raise BackupError(f"{what}: {text[0] if text else type(exc).__name__}") from None


def _sqlite_file(url: str) -> Path | None:
    u = make_url(url)
    return Path(u.database).resolve() if u.drivername.startswith("sqlite") and u.database else None


def _skipped(rel: Path, db_file: Path | None, data_dir: Path) -> bool:
    """Files of the data directory a backup leaves out: the live database (copied by the backup API), per-process
    metrics, lock files and temporary files being written."""
    name = rel.name
    if rel.parts and rel.parts[0] in _SKIP_DIRS:
        return True
    if db_file is not None and name.startswith(db_file.name) and (data_dir / rel).resolve().parent == db_file.parent:
        return True
    return name.endswith((".lock", ".partial")) or ".tmp" in name or name.startswith(".")


def _copy_tree(src: Path, dst: Path, db_file: Path | None, only_new: bool = False) -> int:
    """Copy the data directory's files into ``dst`` (keeping modes); with ``only_new`` those not copied yet.
    A file that disappears while copying (a pruned thumbnail) is left out. Returns the number copied."""
    n = 0
    for root, dirs, files in os.walk(src):
        rroot = Path(root).relative_to(src)
        dirs[:] = [d for d in dirs if not (rroot == Path(".") and d in _SKIP_DIRS)]
        for name in files:
            rel = rroot / name
            if _skipped(rel, db_file, src):
                continue
            target = dst / rel
            if only_new and target.exists():
                continue
            target.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
            try:
                shutil.copy2(Path(root) / name, target)
            except FileNotFoundError:
                continue
            n += 1
    return n


def _pg_command(name: str) -> str:
    found = shutil.which(name)
    if found is None:
        cands = sorted(Path("/usr/lib/postgresql").glob(f"*/bin/{name}"))
        found = str(cands[-1]) if cands else None
    if found is None:
        raise BackupError(f"{name} not found: install the PostgreSQL client tools (e.g. apt-get install postgresql-client)")
    return found


def _pg_args(url: str) -> tuple[str, dict[str, str]]:
    """A libpq connection URI for an SQLAlchemy PostgreSQL URL, and the environment carrying its password (kept
    out of the command line, which other users can read)."""
    u = make_url(url)
    env = dict(os.environ)
    if u.password:
        env["PGPASSWORD"] = str(u.password)
    return u.set(drivername="postgresql", password=None).render_as_string(hide_password=False), env


def _run(cmd: list[str], env: dict[str, str]) -> None:
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
        raise BackupError(f"{Path(cmd[0]).name} failed: {last}")



def _settle_files(engine: Engine, data_dir: Path, files: Path) -> tuple[dict, int, dict]:
    """Stored paths made relative to ``data_dir``, rows of files absent under ``files`` forgotten, the rows counted
    (then ``engine`` disposed)."""
    try:
        return (crud.relativize_paths(engine, data_dir), crud.forget_missing_files(engine, files),
                crud.row_counts(engine))
    finally:
        engine.dispose()


def backup(settings: Settings, dest: Path | str) -> dict:
    """Back the service's database and data directory up into the new folder ``dest`` (see the module docstring).

    Parameters
    ----------
    settings
        The service's settings (data directory, database URL).
    dest
        The backup folder; it must not exist yet (or be empty).

    Returns
    -------
    dict
        The manifest written to ``dest/manifest.json``.

    Raises
    ------
    BackupError
        ``dest`` is not empty, there is no database to back up, or ``pg_dump`` failed.
    """
    dest = Path(dest)
    data_dir = Path(settings.data_dir)
    url = settings.resolved_database_url
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise BackupError(f"{dest}: exists and is not an empty folder; back up into a new folder")
    db_file = _sqlite_file(url)
    if db_file is not None and not db_file.is_file():
        raise BackupError(f"{db_file}: no database to back up (is --data-dir right?)")
    if not data_dir.is_dir():
        raise BackupError(f"{data_dir}: no such data directory")
    partial = dest.with_name(dest.name + ".partial")
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(mode=0o700, parents=True)
    os.chmod(partial, 0o700)
    try:
        manifest = _write_backup(partial, data_dir, url, db_file)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)  # nothing half-written is left behind
        raise
    if dest.exists():
        dest.rmdir()
    partial.rename(dest)
    return manifest


def _write_backup(partial: Path, data_dir: Path, url: str, db_file: Path | None) -> dict:
    """Write the backup into ``partial`` (see :func:`backup`); returns the manifest."""
    files = partial / "data"
    files.mkdir(mode=0o700)
    copied = _copy_tree(data_dir, files, db_file)  # before the snapshot: files that may be pruned meanwhile
    if db_file is not None:
        target = partial / SQLITE_NAME
        os.close(os.open(target, os.O_RDWR | os.O_CREAT, 0o600))
        src = sqlite3.connect(f"{db_file.as_uri()}?mode=ro", uri=True, timeout=60)
        dst = sqlite3.connect(target)
        try:
            src.backup(dst)  # one step: a consistent snapshot; writers in WAL mode are not blocked
            dst.execute("PRAGMA journal_mode=DELETE")  # one self-contained file
            check = dst.execute("PRAGMA integrity_check").fetchone()[0]
            if check != "ok":
                raise BackupError(f"{db_file}: the snapshot fails SQLite's integrity check ({check}); backup not written")
        finally:
            dst.close()
            src.close()
        engine = make_engine(f"sqlite:///{target}")
        db_name, kind = SQLITE_NAME, "sqlite"
    else:
        uri, env = _pg_args(url)
        _run([_pg_command("pg_dump"), "--format=custom", "--no-owner", "--no-privileges", "--file",
              str(partial / PG_NAME), "--dbname", uri], env)
        os.chmod(partial / PG_NAME, 0o600)
        engine = None
        db_name, kind = PG_NAME, "postgresql"
    copied += _copy_tree(data_dir, files, db_file, only_new=True)  # after it: files of frames it holds
    if engine is not None:
        paths, missing, counts = _settle_files(engine, data_dir, files)
    else:
        paths, missing = {}, None  # fixed at restore time (the dump is not rewritten)
        counts = {}
    manifest = {
        "format": FORMAT,
        "created_at": datetime.now(timezone.utc).isoformat(),
        "database": kind,
        "database_file": db_name,
        "source_data_dir": str(data_dir.resolve()),
        "files": copied,
        "paths_relativized": paths.get("relativized", 0),
        "files_missing": missing,
        "integrity_check": "ok" if kind == "sqlite" else None,
        "counts": counts,
    }
    (partial / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def restore(settings: Settings, src: Path | str, *, force: bool = False) -> dict:
    """Restore a backup made by :func:`backup` into the settings' data directory and database.

    Parameters
    ----------
    settings
        Where to restore: the data directory, and the database URL (SQLite under the data directory by default).
    src
        The backup folder.
    force
        Replace an existing database and data-directory files (otherwise their presence is an error).

    Returns
    -------
    dict
        Row counts of the restored database, files restored, and paths made relative or forgotten.

    Raises
    ------
    BackupError
        Not a backup, a backup of the other database kind, a target that already holds data (without ``force``),
        or ``pg_restore`` failed.
    """
    src = Path(src)
    try:
        manifest = json.loads((src / "manifest.json").read_text())
    except (OSError, ValueError):
        raise BackupError(f"{src}: not an illumon backup (no readable manifest.json)") from None
    if manifest.get("format") != FORMAT:
        raise BackupError(f"{src}: backup format {manifest.get('format')!r}, this version reads {FORMAT}")
    data_dir = Path(settings.data_dir)
    url = settings.resolved_database_url
    db_file = _sqlite_file(url)
    kind = manifest.get("database")
    if (kind == "sqlite") != (db_file is not None):
        target_kind = "SQLite" if db_file is not None else "PostgreSQL"
        raise BackupError(f"{src}: a {kind} backup cannot be restored into {target_kind}; restore it into the same "
                          "kind of database")
    dump = src / str(manifest.get("database_file", ""))
    if not dump.is_file():
        raise BackupError(f"{dump}: missing from the backup")
    data_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    present = [p.name for p in data_dir.iterdir() if p.name not in _SKIP_DIRS]
    if db_file is not None:
        if not force and present:
            raise BackupError(f"{data_dir}: not empty ({', '.join(sorted(present)[:4])}); restore into an empty data "
                              "directory, or pass --force to replace it")
        for suffix in ("", "-wal", "-shm", "-journal"):
            Path(f"{db_file}{suffix}").unlink(missing_ok=True)
        tmp = db_file.with_name(db_file.name + ".restore.partial")
        os.close(os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o600))
        s_conn = sqlite3.connect(f"{dump.resolve().as_uri()}?mode=ro", uri=True)
        d_conn = sqlite3.connect(tmp)
        try:
            s_conn.backup(d_conn)
        finally:
            d_conn.close()
            s_conn.close()
        tmp.replace(db_file)
    else:
        engine = make_engine(url)
        try:
            if not force and (crud.has_cameras(engine) or present):
                raise BackupError("the target database or data directory already holds illumon data; restore into an "
                                  "empty one, or pass --force to replace it")
        finally:
            engine.dispose()
        uri, env = _pg_args(url)
        _run([_pg_command("pg_restore"), "--clean", "--if-exists", "--no-owner", "--no-privileges",
              "--single-transaction", "--dbname", uri, str(dump)], env)
    restored = _copy_tree(src / "data", data_dir, None) if (src / "data").is_dir() else 0
    # make_engine brings an older backup's schema up to this version
    paths, forgotten, counts = _settle_files(make_engine(url), data_dir, data_dir)
    return {"restored_from": str(src), "database": kind, "files": restored, "counts": counts,
            "paths_relativized": paths["relativized"], "files_missing": forgotten}

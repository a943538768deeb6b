"""Where a sweep's Optuna study lives: storage URLs (SQLite, PostgreSQL/MySQL, journal files),
opening them safely when several workers start at once, and the files that tie a sweep directory
and its trials to their study. Shared by the sweeper plugin and ``python -m roto_trl.sweep``."""

from __future__ import annotations

import json
import random
import re
import time
import warnings
from pathlib import Path

import optuna
import sqlalchemy.exc

STUDY_FILE = "study.json"  # in the sweep directory: which study (name, storage) it belongs to
TRIAL_FILE = "trial.json"  # in a trial's run directory: which study and trial it is
DEFAULT_DB = "study.db"  # the default storage: SQLite in the sweep directory
JOURNAL = "journal://"  # storage prefix of an Optuna journal file: journal://<path>
RDB_SCHEMES = ("sqlite", "postgresql", "mysql")
TABLE_RACE_ATTEMPTS = 5  # tries to open a fresh database that other workers are creating tables in



def storage_url(storage: str | None, sweep_dir: Path) -> str:
    """The study's storage: ``storage`` as given, or SQLite in the sweep directory."""
    return storage or f"sqlite:///{(Path(sweep_dir) / DEFAULT_DB).resolve()}"


def redact(url: str) -> str:
    """``url`` with its password (``scheme://user:password@host``) replaced by ``***``."""
    return re.sub(r"(://[^:/@]*:)[^@/]*@", r"\1***@", url)


def open_storage(
    url: str, *, heartbeat_interval: int | None = None, grace_period: int | None = None
) -> optuna.storages.BaseStorage:
    """The Optuna storage at ``url``.

    ``journal://<path>`` is a ``JournalStorage`` on a file (``journal:///abs/path.log``; on a
    shared file system for many machines); ``sqlite://``, ``postgresql[+driver]://`` and
    ``mysql[+driver]://`` are SQLAlchemy URLs for ``RDBStorage``, which records heartbeats of
    running trials every ``heartbeat_interval`` seconds when one is given. Workers starting at
    once on a fresh database race to create Optuna's tables (PostgreSQL's ``CREATE ... IF NOT
    EXISTS`` is not atomic): the loser gets a duplicate-key error, waits and opens it again.
    """
    if url.startswith(JOURNAL):
        path = Path(url.removeprefix(JOURNAL))
        path.parent.mkdir(parents=True, exist_ok=True)
        return optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(path)))
    scheme = url.split("://", 1)[0].split("+", 1)[0] if "://" in url else ""
    if scheme not in RDB_SCHEMES:
        raise ValueError(
            f"storage {redact(url)!r}: unknown kind; use sqlite:///<file>, postgresql://<user>@<host>/<db>, "
            f"mysql://..., or {JOURNAL}<file>"
        )
    for attempt in range(1, TABLE_RACE_ATTEMPTS + 1):
        try:
            return _rdb_storage(url, heartbeat_interval, grace_period)
        except (sqlalchemy.exc.IntegrityError, sqlalchemy.exc.ProgrammingError):
            if attempt == TABLE_RACE_ATTEMPTS:
                raise
            time.sleep(0.5 + random.random())  # let the winner finish creating the tables


def _rdb_storage(
    url: str, heartbeat_interval: int | None, grace_period: int | None
) -> optuna.storages.RDBStorage:
    with warnings.catch_warnings():  # heartbeats are "experimental" in Optuna since 2.9
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        try:
            return optuna.storages.RDBStorage(
                url,
                engine_kwargs={"pool_pre_ping": True},  # survive connections dropped during long trials
                heartbeat_interval=heartbeat_interval,
                grace_period=grace_period,
            )
        except ImportError as err:
            raise ValueError(f"storage {redact(url)!r} needs a database driver: {err}") from None


def record_study(sweep_dir: Path, study_name: str, storage: str | None) -> None:
    """Write ``<sweep_dir>/study.json``: the study this directory belongs to (no password;
    storage null: ``study.db`` in this directory, wherever it is moved)."""
    info = {"study_name": study_name, "storage": redact(storage) if storage else None}
    (Path(sweep_dir) / STUDY_FILE).write_text(json.dumps(info, indent=2) + "\n")


def load_study(sweep_dir: Path, storage: str | None = None, study_name: str | None = None) -> optuna.Study:
    """The study of a sweep directory (``study.json``), or of ``storage`` and ``study_name``."""
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise FileNotFoundError(f"no sweep directory {sweep_dir}")
    info_path = sweep_dir / STUDY_FILE
    info = json.loads(info_path.read_text()) if info_path.is_file() else {}
    if not info and (storage is None or study_name is None):
        raise FileNotFoundError(f"{sweep_dir} holds no {STUDY_FILE}; give --storage and --study")
    url = storage_url(storage or info.get("storage"), sweep_dir)
    if "***@" in url:
        raise ValueError(f"the storage in {info_path} hides its password; give it with --storage URL")
    name = study_name or info["study_name"]
    try:
        return optuna.load_study(study_name=name, storage=open_storage(url))
    except KeyError:
        raise ValueError(f"no study {name!r} in {redact(url)}") from None

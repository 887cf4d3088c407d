"""What a tracking URI may be, and the one safe first open of a sqlite store.

:func:`normalize_tracking_uri` is the single gate every command's ``--tracking-uri`` (and
``MLFLOW_TRACKING_URI``) goes through (``create_tracker``, ``uavbench ui``, ``uavbench sync``):

- a URI with a scheme MLflow's tracking stores accept (``http(s)``, ``sqlite``, ``postgresql``,
  ``mysql``, ``mssql``, ``databricks``...) is kept as given;
- a plain path ending in ``.db`` / ``.sqlite`` / ``.sqlite3`` becomes ``sqlite:///<absolute path>``
  (said once, as a :func:`~benchmark.progress.status` line), which is what
  ``--tracking-uri ./mlflow.db`` means;
- anything else (a directory, ``mlruns``, ``file:`` store, a typo'd scheme) is refused with a
  :class:`~benchmark.errors.InputError` naming the value and the fix. Before, such a value made
  MLflow fail at open and every run went silently to the local fallback.

:func:`open_sqlite_store_once`: MLflow creates and migrates a sqlite schema on the first open,
without any lock; two processes opening a fresh store at once race in the migration
(``duplicate column name: step``, ``table _alembic_tmp_tags already exists``) and one of them
fails. The first open therefore happens under an exclusive lock file beside the database
(``<db>.lock``, :func:`benchmark.locks.work_lock`): exactly one process migrates, the others wait
and then open a finished schema.
"""

from __future__ import annotations

import os
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar
from urllib.parse import urlsplit

from benchmark.errors import InputError
from benchmark.progress import status

# Schemes of MLflow 3's tracking store registry (mlflow.tracking._tracking_service.utils) that
# give a working store; "file" only with MLFLOW_ALLOW_FILE_STORE (MLflow 3 refuses it otherwise).
_SCHEMES = {
    *("http", "https", "sqlite", "postgresql", "mysql", "mssql"),
    *("databricks", "databricks-uc", "uc"),
}
SQLITE_SUFFIXES = (".db", ".sqlite", ".sqlite3")
# How long a process waits for another one to finish creating a store's schema (a fresh schema
# takes a few seconds; a waiting process then opens it at once).
SCHEMA_LOCK_TIMEOUT_S = 300.0
_SAID: set[str] = set()  # paths already reported as "becomes sqlite:///..." in this process

T = TypeVar("T")


def normalize_tracking_uri(value: str | None, source: str = "tracking_uri") -> str | None:
    """``value`` as a URI MLflow opens, ``None`` for ``None``/blank (the caller's default).

    ``source`` names where the value came from in the messages: the argument or config field
    (``tracking_uri``, ``target``) or the variable ``MLFLOW_TRACKING_URI``; never a command-line
    flag (the library does not know them). Raises :class:`InputError` for a value that is no
    usable store.
    """
    if value is None or not value.strip():
        return None
    value = value.strip()
    scheme = urlsplit(value).scheme.lower()
    # "C:\\x.db" parses with scheme "c": a one-letter scheme is a Windows drive, i.e. a path.
    if scheme and len(scheme) > 1:
        base = scheme.split("+", 1)[0]  # postgresql+psycopg2://
        if base in _SCHEMES:
            return value.rstrip("/") if base in ("http", "https") else value
        if base == "file" and os.environ.get("MLFLOW_ALLOW_FILE_STORE", "").lower() == "true":
            return value
        if base == "file":
            raise InputError(
                f"{source} {value!r}: MLflow 3 no longer writes file stores; give a sqlite "
                "database instead, e.g. ./mlflow.db (becomes sqlite:///<absolute path>)"
            )
        raise InputError(
            f"{source} {value!r}: unknown tracking URI scheme {scheme!r}; expected an "
            "http(s):// server URL, a sqlite:///path.db URI or a path ending in .db"
        )
    path = Path(value).expanduser()
    if path.suffix.lower() in SQLITE_SUFFIXES and not path.is_dir():
        uri = f"sqlite:///{path.resolve()}"
        if value not in _SAID:
            _SAID.add(value)
            # A note while the work starts, not a result: the status channel (which a Python
            # caller can capture or silence) rather than a print.
            status(f"note: {value} is a path: using the store {uri}")
        return uri
    what = "a directory" if path.is_dir() else "a path that is not a sqlite database"
    raise InputError(
        f"{source} {value!r} is {what}, not a tracking store; give a database file such as "
        f"{(path / 'mlflow.db') if path.is_dir() else path.with_suffix('.db')} (used as "
        "sqlite:///<absolute path>), a sqlite:/// URI or an http(s):// server URL"
    )


def default_tracking_uri(cwd: str | Path | None = None) -> str:
    """``MLFLOW_TRACKING_URI`` if set, else ``sqlite:///<cwd>/mlflow.db`` (absolute path)."""
    env = normalize_tracking_uri(os.environ.get("MLFLOW_TRACKING_URI"), "MLFLOW_TRACKING_URI")
    if env:
        return env
    base = Path(cwd) if cwd is not None else Path.cwd()
    return f"sqlite:///{(base / 'mlflow.db').resolve()}"


def server_is_healthy(uri: str, timeout: float = 5.0) -> tuple[bool, str]:
    """``GET <uri>/health`` with ``timeout`` seconds; ``(ok, reason)``. Never raises."""
    url = uri.rstrip("/") + "/health"
    try:
        with urllib.request.urlopen(url, timeout=timeout) as resp:
            body = resp.read(64).decode("utf-8", "replace").strip()
            if resp.status == 200:
                return True, body
            return False, f"HTTP {resp.status} from {url}"
    except (urllib.error.URLError, OSError, ValueError) as err:
        reason = getattr(err, "reason", err)
        return False, f"{url}: {reason}"


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (absolute or relative to the cwd), else None.
    ``sqlite://`` with nothing after it (an in-memory database) is None too."""
    if not uri.startswith("sqlite:///"):
        return None
    rest = uri[len("sqlite:///") :].split("?", 1)[0]
    return Path(rest) if rest and rest != ":memory:" else None


def uri_key(uri: str) -> str:
    """A canonical spelling of ``uri`` to compare stores: a server URL without its trailing
    slash, a sqlite URI with its absolute path."""
    db = sqlite_path(uri)
    if db is not None:
        return f"sqlite:///{db.resolve()}"
    return uri.rstrip("/")


def open_sqlite_store_once(uri: str, open_store: Callable[[], T]) -> T:
    """``open_store()`` (the first MLflow call on ``uri``, which creates or migrates the schema;
    note that ``MlflowClient(uri)`` itself opens the store, so build the client inside it),
    under the lock file ``<db>.lock`` when ``uri`` is a sqlite database; plainly otherwise.

    The database's directory is created if missing. A filesystem that cannot lock, or a lock
    held past ``SCHEMA_LOCK_TIMEOUT_S``, opens without the lock (as MLflow itself would) rather
    than refuse to track.
    """
    db = sqlite_path(uri)
    if db is None:
        return open_store()
    from benchmark.locks import LockBusyError, work_lock

    db = db.resolve()
    db.parent.mkdir(parents=True, exist_ok=True)
    try:
        with work_lock(
            db.with_name(db.name + ".lock"),
            what="MLflow schema setup",
            wait=True,
            poll_s=0.2,
            timeout_s=SCHEMA_LOCK_TIMEOUT_S,
        ):
            return open_store()
    except LockBusyError:
        return open_store()

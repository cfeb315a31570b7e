"""The run directory: its layout, its files and their integrity. Training, ``transam
evaluate``, the grid and the report all read and write runs through this module, so each part
of the format lives here once.

Layout (``--out``)::

    config.json            the run's settings (written once, atomically)
    partners.json          which partner population it trains against (the choice or the
                           population directory's absolute path, and its digest)
    final.json             written last: the run is finished (its final evaluation per seed)
    metrics.jsonl          one JSON object per chunk (= per evaluation point)
    tb/                    TensorBoard event files (same scalars, plus steps/s)
    checkpoints/           chunk_NNNNNN.msgpack: the whole runner state and its SHA-256
                           (last two kept; one that fails verification becomes *.corrupt)
    eval_PARTNERS.json     `transam evaluate` outputs (with .png and _pca.npz beside it)
    .lock                  held (flock) by the one process training or evaluating the run

With ``--num-seeds n > 1`` the per-seed files (metrics.jsonl, tb/, checkpoints/, evaluations)
sit in ``seed_S/`` subdirectories and config.json / partners.json / final.json at the top.
Both seed modes write the same layout, so a run can be resumed in either mode.

Integrity:

* **Atomic writes** (:func:`write_atomic`): a temporary file in the same directory, fsynced,
  renamed over the target. A failed write (disk full, a read-only or vanished ``--out``) removes
  the temporary file, leaves the target's previous contents untouched and raises
  :class:`WriteError` naming the path.
* **Verified checkpoints** (:func:`save_checkpoint`, :func:`read_checkpoint`): each
  ``chunk_NNNNNN.msgpack`` is a msgpack map ``{"format": "transam-checkpoint", "version": 1,
  "sha256": ..., "state": <the flax-serialised RunnerState>}``; reading checks the digest, then
  decodes the state against the run's structure. A file written before the checksum existed
  (the bare flax msgpack) is verified by decoding alone. The newest ``KEEP_CHECKPOINTS`` are
  kept so that a corrupt newest one has a predecessor; :func:`newest_good_checkpoint` reports
  each one that fails (by name, on stderr) and falls back to the newest good one.
* **One writer** (:func:`run_lock`): ``--out/.lock``, held with ``fcntl.flock`` by train,
  resume and evaluate for as long as they write. The kernel drops the lock when its process
  dies, however it dies, so a stale ``.lock`` file never blocks a resume; the file only names
  the holder (pid, host, command) for the error message. Where the filesystem has no flock
  (some NFS mounts), the holder's pid is checked instead: a live process on this host blocks,
  a dead one does not.
* **The same run** (:func:`prepare_run_dir`): ``--resume`` refuses changed settings
  (config.json) and a changed partner population (partners.json's digest). The one setting
  it may change is a larger ``total_steps``, where the learning-rate schedule does not depend
  on the run length: the run is continued ('extend'), finished or not, exactly as a run set
  for the larger length from the start would have gone on.

Stopping on SIGINT/SIGTERM is the training loop's (:mod:`transam.train.stop`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import socket
import sys
import time
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgpack
from flax import serialization

from transam.compose import partner_choices
from transam.train.config import ConfigError, TrainConfig, comparable, with_added_settings

KEEP_CHECKPOINTS = 2
LOCK_FILE = ".lock"
CHECKPOINT_FORMAT = "transam-checkpoint"
CHECKPOINT_VERSION = 1
CORRUPT_SUFFIX = ".corrupt"
POPULATION_FILE = "partners.json"
OWN_ENTRIES = ("config.json", POPULATION_FILE, "final.json", "metrics.jsonl", "tb", "checkpoints")
"""What a run writes at its top level (``--force`` deletes these and ``seed_*/``, nothing else)."""
EVAL_PARTNERS: tuple[str, ...] = ("train", "heldout")
"""The named partner choices of ``transam evaluate`` (besides a population directory)."""


# ---------------------------------------------------------------- atomic writes


class WriteError(OSError):
    """A file of the run could not be written; its previous version (if any) is untouched."""

    def __init__(self, path: Path, err: OSError, hint: str = "") -> None:
        super().__init__(err.errno, err.strerror or str(err))
        self.path = path
        self.hint = hint

    def __str__(self) -> str:
        hint = f"; {self.hint}" if self.hint else ""
        return f"cannot write {self.path}: {self.strerror}{hint}"


def write_atomic(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same directory, then rename over ``path``."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise WriteError(path, err) from err


def write_json(path: Path, obj: Any) -> None:
    write_atomic(path, (json.dumps(obj, indent=2) + "\n").encode())


# ---------------------------------------------------------------- metrics.jsonl


class MetricsError(ConfigError):
    """A metrics file line that is not a record (other than a torn last line): the file is
    damaged, and reading on would silently lose records. A :class:`ConfigError`, so that the
    command line reports it as an error naming the file, not a traceback."""


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """The records of a metrics.jsonl (or any JSON-lines file written a record at a time).

    A torn last line, the end of a write cut off by a kill (no newline after it, and not a
    record), is dropped; any other line that is not a JSON object raises
    :class:`MetricsError` with its line number.
    """
    if not path.exists():
        return []
    lines = path.read_text().split("\n")  # the last item: after the final newline ("" if whole)
    records = []
    for number, line in enumerate(lines, 1):
        last = number == len(lines)
        if last and not line:
            break
        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            if last:  # torn: its write never reached the newline
                break
            raise MetricsError(f"{path}, line {number}: not a JSON record ({err})") from None
        if not isinstance(record, dict):
            if last:
                break
            raise MetricsError(f"{path}, line {number}: not a JSON object: {line[:80]!r}")
        records.append(record)
    return records


def truncate_metrics(seed_dir: Path, chunk: int) -> None:
    """Drop the metrics records of chunks from ``chunk`` on (a resume recomputes them)."""
    path = seed_dir / "metrics.jsonl"
    kept = [r for r in read_metrics(path) if r.get("chunk", -1) < chunk]
    write_atomic(path, "".join(json.dumps(r) + "\n" for r in kept).encode())


# ---------------------------------------------------------------- config.json


def _from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    """Rebuild a (nested) frozen dataclass from its ``asdict`` form; lists become tuples, so
    the result is hashable like the original."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where}: unknown setting(s) {', '.join(unknown)} for {cls.__name__}; "
            f"valid: {', '.join(sorted(names))}"
        )
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            kwargs[name] = _from_dict(hint, value, where)  # type: ignore[arg-type]
        else:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
    return cls(**kwargs)


def read_config(path: str | Path) -> TrainConfig:
    """The TrainConfig a config.json file holds, as saved (settings added since filled in with
    their old values; a multi-seed run's as one config, ``out`` as recorded)."""
    saved = with_added_settings(json.loads(Path(path).read_text()))
    config: TrainConfig = _from_dict(TrainConfig, saved, str(path))
    return config


def load_run_config(run_dir: str | Path) -> TrainConfig:
    """The TrainConfig of a single-seed run directory (``out`` set to it), or of one seed's
    ``seed_S`` subdirectory of a multi-seed run."""
    run_dir = Path(run_dir)
    path = run_dir / "config.json"
    seed = None
    if not path.exists():
        match = re.fullmatch(r"seed_(\d+)", run_dir.name)
        if match and (run_dir.parent / "config.json").exists():
            path, seed = run_dir.parent / "config.json", int(match.group(1))
        else:
            inside = sorted(str(c.parent) for c in run_dir.glob("*/config.json"))
            hint = f"; runs inside it: {', '.join(inside)}" if inside else ""
            raise ConfigError(f"{str(run_dir)!r} holds no transam run (no config.json){hint}")
    config = read_config(path)
    if seed is not None:
        seeds = range(config.seed, config.seed + config.num_seeds)
        if config.num_seeds == 1 or seed not in seeds:
            raise ConfigError(
                f"{str(run_dir)!r} is not a seed of the run in {str(run_dir.parent)!r} "
                f"(its seeds: {', '.join(map(str, seeds))})"
            )
        config = dataclasses.replace(config, seed=seed, num_seeds=1)
    elif config.num_seeds > 1:
        subdirs = [str(run_dir / f"seed_{config.seed + i}") for i in range(config.num_seeds)]
        raise ConfigError(
            f"{str(run_dir)!r} holds {config.num_seeds} seeds; evaluate one seed directory: "
            f"{', '.join(subdirs)}"
        )
    return dataclasses.replace(config.validate(), out=str(run_dir), progress=False)


def seed_dirs(config: TrainConfig) -> list[Path]:
    """Where each seed of a run writes its per-seed files (the run directory itself for one)."""
    out = Path(config.run_dir)
    seeds = [config.seed + i for i in range(config.num_seeds)]
    return [out] if config.num_seeds == 1 else [out / f"seed_{s}" for s in seeds]


# ---------------------------------------------------------------- partners.json


def population_record(config: TrainConfig) -> dict[str, Any]:
    """What partners.json says: the environment, the partner choice and the population's
    digest (None for the scripted population)."""
    from transam.partners.learned import population_digest

    digest = population_digest(config.env, config.partners)
    return {"env": config.env, "partners": config.partners, "digest": digest}


def recorded_population(out: Path) -> dict[str, Any] | None:
    """The run's partners.json, or None for a run written before that file existed (nothing
    says which population it used)."""
    path = out / POPULATION_FILE
    return json.loads(path.read_text()) if path.exists() else None


def _check_population(out: Path, config: TrainConfig) -> None:
    """Refuse to resume against a different shipped population than the run started with."""
    recorded = recorded_population(out)
    if recorded is None:
        return
    was, now = recorded["digest"], population_record(config)["digest"]
    shipped = config.partners in partner_choices(config.env)
    how = "the transam version it started with" if shipped else "the directory as it was"
    if was != now:
        raise RunDirError(
            f"--resume: the {config.env} partner population {config.partners!r} "
            f"changed since the run in {str(out)!r} started (run: {was}, now: {now}); finish "
            f"it with {how}, or --force to start over"
        )


# ---------------------------------------------------------------- fresh, resume or finished


class RunDirError(ConfigError):
    """The run directory holds something that the requested action would overwrite."""


def prepare_run_dir(config: TrainConfig) -> str:
    """Decide what to do with ``--out`` before writing anything: 'fresh', 'resume' or
    'finished'. Raises :class:`RunDirError` when it would overwrite a run without --force."""
    out = Path(config.run_dir)
    if out.exists() and not out.is_dir():
        raise RunDirError(f"--out {str(out)!r} exists and is not a directory")
    entries = {p.name for p in out.iterdir()} - {LOCK_FILE} if out.exists() else set()
    if not entries and config.resume and not config.force:
        raise RunDirError(
            f"--resume: no run in --out {str(out)!r} to continue; drop --resume to start one"
        )
    if not entries:
        return "fresh"
    if "config.json" not in entries:
        raise RunDirError(
            f"--out {str(out)!r} is not empty and holds no transam run; choose another directory"
        )
    finished = "final.json" in entries
    if config.force:
        return "fresh"
    if not config.resume:
        what = "a finished run" if finished else "an unfinished run"
        hint = "" if finished else " --resume to continue it, or"
        raise RunDirError(
            f"--out {str(out)!r} holds {what}; pass{hint} --force to delete it and start over"
        )
    saved = comparable(with_added_settings(json.loads((out / "config.json").read_text())))
    wanted = comparable(json.loads(json.dumps(config.identity())))
    if saved != wanted and _extends(out, saved, wanted, config):
        _check_population(out, config)
        return "extend"
    if saved != wanted:
        diff = sorted(_diff(saved, wanted))
        raise RunDirError(
            f"--resume: settings differ from the run in {str(out)!r}: {', '.join(diff)} "
            "(resume with the same settings, or --force to start over)"
        )
    if not finished:
        _check_population(out, config)
    return "finished" if finished else "resume"


def _extends(out: Path, saved: dict[str, Any], wanted: dict[str, Any], config: TrainConfig) -> bool:
    """Whether ``--resume`` asks to continue the run to a larger ``total_steps`` and nothing
    else; raises where it asks for that but cannot have it (a shorter run, or a learning-rate
    schedule that depends on the run length, so the steps done so far would differ)."""
    if {**saved, "total_steps": wanted["total_steps"]} != wanted:
        return False
    before, now = saved["total_steps"], wanted["total_steps"]
    if now < before:
        raise RunDirError(
            f"--resume --total-steps {now}: the run in {str(out)!r} was set for {before} steps; "
            "a run can be continued to more steps, not fewer"
        )
    if config.schedule_by_run:
        raise RunDirError(
            f"--resume --total-steps {now}: the run in {str(out)!r} anneals its learning rate "
            f"over its own {before} steps, so a longer run would have trained differently from "
            "the start; continue only runs started with --a2c.anneal-steps N (or "
            "--a2c.no-anneal-lr), or start over with --force"
        )
    return True


def _diff(a: Any, b: Any, prefix: str = "") -> Iterator[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            yield from _diff(a.get(k), b.get(k), f"{prefix}{k}.")
    elif a != b:
        name = prefix.rstrip(".")
        yield f"{name} (run: {a!r}, now: {b!r}; the run's flag: {_flag(name, a)})"


def _flag(name: str, value: Any) -> str:
    """The command-line flag that sets setting ``name`` (e.g. 'a2c.time_feature') to ``value``."""
    group, _, leaf = name.rpartition(".")
    if value is False:
        leaf = f"no_{leaf}"  # tyro's negated boolean flag
    flag = "--" + ".".join(filter(None, (group, leaf))).replace("_", "-")
    return flag if isinstance(value, bool) else f"{flag} {value}"


def start_run_dir(config: TrainConfig) -> None:
    """Write a fresh run's config.json and partners.json (creating ``--out``)."""
    out = Path(config.run_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "config.json", config.identity())
    write_json(out / POPULATION_FILE, population_record(config))


def extend_run_dir(config: TrainConfig) -> None:
    """Set a run for the larger ``config.total_steps`` (see :func:`prepare_run_dir`). The old
    final.json goes first: interrupted in between, the run is an unfinished run of its old
    length, which a resume finishes and a second extension continues."""
    out = Path(config.run_dir)
    (out / "final.json").unlink(missing_ok=True)
    write_json(out / "config.json", config.identity())


def clean_run_dir(out: Path) -> None:
    """Delete what a previous run wrote (and nothing else) in ``out``."""
    for p in out.iterdir():
        if p.name in OWN_ENTRIES or (p.is_dir() and p.name.startswith("seed_")):
            shutil.rmtree(p) if p.is_dir() else p.unlink()


def read_final(out: Path) -> list[dict[str, Any]]:
    """The per-seed final records of a finished run's final.json."""
    return json.loads((out / "final.json").read_text())["seeds"]


def write_final(out: Path, finals: list[dict[str, Any]]) -> None:
    """Mark the run finished: final.json with each seed's final record."""
    write_json(out / "final.json", {"seeds": finals})


# ---------------------------------------------------------------- evaluation outputs


NO_DROPOUT_SUFFIX = "-nodropout"
"""appended to an evaluation's output names when it acted without the agent model's dropout
(``transam evaluate --no-dropout``), so that it never overwrites the run's own evaluation"""


def evaluation_label(partners: str, dropout: bool = True) -> str:
    """The name part of ``partners``' output files: ``train``, ``heldout``, or ``pop-NAME``
    for a population directory NAME (characters outside ``[A-Za-z0-9_.-]`` become ``_``),
    followed by :data:`NO_DROPOUT_SUFFIX` without ``dropout``."""
    label = (
        partners
        if partners in EVAL_PARTNERS
        else ("pop-" + re.sub(r"[^A-Za-z0-9_.-]", "_", Path(partners).resolve().name))
    )
    return label if dropout else label + NO_DROPOUT_SUFFIX


def evaluation_path(run_dir: str | Path, partners: str, dropout: bool = True) -> Path:
    """Where ``transam evaluate`` writes its JSON (the figure, ``.png``, sits beside it)."""
    return Path(run_dir) / f"eval_{evaluation_label(partners, dropout)}.json"


def starts_evaluation_path(run_dir: str | Path, starts: str | Path, dropout: bool = True) -> Path:
    """Where ``transam evaluate --starts FILE`` writes its JSON."""
    suffix = "" if dropout else NO_DROPOUT_SUFFIX
    return Path(run_dir) / f"eval_starts-{Path(starts).stem}{suffix}.json"


def projection_path(run_dir: str | Path, partners: str, dropout: bool = True) -> Path:
    """Where ``transam evaluate`` writes the 2-D projection of the embeddings."""
    return Path(run_dir) / f"eval_{evaluation_label(partners, dropout)}_pca.npz"


# ---------------------------------------------------------------- checkpoints


class CheckpointError(ValueError):
    """A checkpoint file failed verification (truncated, corrupt, or not a run state)."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"checkpoint {path} failed verification: {reason}")
        self.path = path
        self.reason = reason


def checkpoints(seed_dir: Path) -> dict[int, Path]:
    """A run's checkpoint files by chunk index (what --resume, evaluation and the grid read)."""
    found = {}
    for p in (seed_dir / "checkpoints").glob("chunk_*.msgpack"):
        try:
            found[int(p.stem.split("_")[1])] = p
        except ValueError:
            continue
    return found


def find_checkpoint(run_dir: str | Path, checkpoint: str | int | None = None) -> Path:
    """The newest checkpoint of ``run_dir``, or the named one (a file name such as
    ``chunk_000003.msgpack``, with or without the suffix, or a chunk number). Not verified:
    its reader falls back past a bad newest one (:func:`newest_good_checkpoint`)."""
    found = checkpoints(Path(run_dir))
    names = ", ".join(p.name for _, p in sorted(found.items()))
    if not found:
        raise ConfigError(f"no checkpoints in {str(Path(run_dir) / 'checkpoints')!r}")
    if checkpoint is None:
        return found[max(found)]
    name = Path(str(checkpoint)).name.removesuffix(".msgpack").removeprefix("chunk_")
    if name.isdigit() and int(name) in found:
        return found[int(name)]
    raise ConfigError(f"checkpoint {checkpoint!r} not found in {str(run_dir)!r}; have: {names}")


def checkpoint_bytes(state: Any) -> bytes:
    """The bytes of a checkpoint of ``state``: the flax msgpack of the state inside a map that
    carries its SHA-256."""
    payload = serialization.to_bytes(state)
    return msgpack.packb(
        {
            "format": CHECKPOINT_FORMAT,
            "version": CHECKPOINT_VERSION,
            "sha256": hashlib.sha256(payload).hexdigest(),
            "state": payload,
        },
        use_bin_type=True,
    )


def read_checkpoint(path: Path, template: Any) -> Any:
    """The state in checkpoint ``path``, restored onto ``template``'s structure; raises
    :class:`CheckpointError` when the file is unreadable, truncated or does not verify."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise CheckpointError(path, f"unreadable ({err.strerror})") from err
    if not data:
        raise CheckpointError(path, "empty file")
    try:
        outer = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as err:  # msgpack raises several types for truncated input
        raise CheckpointError(path, f"not a complete msgpack file ({err})") from err
    if isinstance(outer, dict) and outer.get("format") == CHECKPOINT_FORMAT:
        payload = outer.get("state")
        if not isinstance(payload, bytes):
            raise CheckpointError(path, "no state inside")
        digest = hashlib.sha256(payload).hexdigest()
        if digest != outer.get("sha256"):
            raise CheckpointError(path, f"checksum mismatch (stored {outer.get('sha256')})")
    else:
        payload = data  # written before checksums: the bare flax state (decoding verifies it)
    try:
        return serialization.from_bytes(template, payload)
    except Exception as err:
        reason = f"not a state of this run ({type(err).__name__}: {err})"
        raise CheckpointError(path, reason) from err


def save_checkpoint(seed_dir: Path, chunk: int, state: Any) -> Path:
    ckpt_dir = seed_dir / "checkpoints"
    path = ckpt_dir / f"chunk_{chunk:06d}.msgpack"
    previous = max(checkpoints(seed_dir).items(), default=None)
    try:
        ckpt_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(path, checkpoint_bytes(state))
    except OSError as err:
        kept = f"the previous checkpoint {previous[1]} is intact" if previous else "none kept"
        raise WriteError(
            path, err, f"{kept}; free space or fix the directory, then resume with --resume"
        ) from err
    return path


def prune_checkpoints(seed_dir: Path, keep: int = KEEP_CHECKPOINTS) -> None:
    """Keep the newest ``keep`` checkpoints (0: all); drop temporary files of earlier writers
    (killed mid-write: the caller holds the run's lock, so no one else is writing)."""
    for _, p in sorted(checkpoints(seed_dir).items())[:-keep] if keep else ():
        p.unlink(missing_ok=True)
    for p in (seed_dir / "checkpoints").glob(".chunk_*.msgpack.tmp*"):
        p.unlink(missing_ok=True)


def warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


def newest_good_checkpoint(
    dirs: list[Path],
    template: Any,
    quarantine: bool = False,
    report: Callable[[str], None] = warn,
) -> tuple[int, list[Any]] | None:
    """(chunk, one state per directory) of the newest chunk checkpointed and verified in every
    directory of ``dirs`` (the seeds of one group), or None when there is none. Every
    checkpoint that fails verification is reported by name; with ``quarantine`` (training,
    which holds the run's lock) it is also renamed to ``*.msgpack.corrupt`` so that it is
    neither read again nor counted among the kept checkpoints."""
    found = [checkpoints(d) for d in dirs]
    common = set.intersection(*(set(f) for f in found)) if found else set()
    for chunk in sorted(common, reverse=True):
        states, bad = [], []
        for f in found:
            try:
                states.append(read_checkpoint(f[chunk], template))
            except CheckpointError as err:
                bad.append(err)
        for failed in bad:
            aside = ""
            if quarantine:
                target = failed.path.with_name(failed.path.name + CORRUPT_SUFFIX)
                with contextlib.suppress(OSError):
                    failed.path.replace(target)
                    aside = f"; moved aside to {target.name}"
            report(f"{failed}{aside}; falling back to an older checkpoint")
        if not bad:
            return chunk, states
    return None


# ---------------------------------------------------------------- one writer per run directory


class RunLockedError(ConfigError):
    """Another process holds the run directory's lock."""


def _holder(fd: int) -> dict[str, Any]:
    try:
        text = os.pread(fd, 4096, 0).decode()
        info = json.loads(text) if text.strip() else {}
    except (OSError, ValueError):
        return {}
    return info if isinstance(info, dict) else {}


def _describe(info: dict[str, Any]) -> str:
    if not info.get("pid"):
        return "another process"
    since = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(info.get("since", 0)))
    return (
        f"process {info['pid']} on {info.get('host', '?')} ({info.get('command', '?')}, "
        f"since {since})"
    )


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def run_lock(out: Path, command: str) -> Iterator[None]:
    """Hold ``out``'s lock (creating ``out`` if needed) for the duration; raises
    :class:`RunLockedError` naming the holder when another live process has it, and
    :class:`WriteError` when ``out`` cannot be created or written."""
    path = out / LOCK_FILE
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        raise WriteError(path, err, f"is --out {str(out)!r} writable?") from err
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            info = _holder(fd)
            kill = f" (kill {info['pid']})" if info.get("pid") else ""
            raise RunLockedError(
                f"{str(out)!r} is in use by {_describe(info)}: one process at a time may "
                f"train, resume or evaluate a run; wait for it to end or stop it{kill}"
            ) from None
        except OSError as err:  # no flock on this filesystem: check the recorded holder
            if err.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                raise WriteError(path, err) from err
            info = _holder(fd)
            pid, host = info.get("pid"), info.get("host")
            if pid and pid != os.getpid() and (host != socket.gethostname() or _alive(pid)):
                where = "" if host == socket.gethostname() else f"; if it has ended, delete {path}"
                raise RunLockedError(
                    f"{str(out)!r} is in use by {_describe(info)} (this filesystem has no "
                    f"flock; the lock file names it){where}"
                ) from None
        me = {"pid": os.getpid(), "host": socket.gethostname(), "command": command}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({**me, "since": time.time()}).encode(), 0)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # nobody holds it now
    finally:
        os.close(fd)  # releases the flock

"""A set of files that lands whole or not at all: what a publish or ship step writes.

A :class:`Publication` is opened over *areas* (folders or files under one root: ``results/``,
``figures/``, ``checkpoints/paper_fit/threed``) and *documents* (files with spliced blocks, such
as README.md). It copies the areas into a stage, ``<root>/.publish/stage/``; the step writes there
(:meth:`Publication.staged` maps a path of the root to its place in the stage). On a clean exit
the files that changed land in one final step:

1. the documents are refreshed from the staged files (``refresh``, a callback: the splicing lives
   in ``report/``), read from the root just before they land;
2. the files to move and to remove are listed, atomically, in ``.publish/journal.json``: the
   point of commitment;
3. each file is renamed onto its place (``os.replace``, atomic per file) while stop signals wait;
   the journal and the stage are removed.

A stop signal or an error before 2 discards the stage: every file under the root is as it was.
A signal during 3 waits for the last file to land, then stops the process. A process killed
during 3 (SIGKILL, a power cut) leaves the journal: the next publication under that root
(:func:`recover`) first finishes its moves, so the set lands whole. One publication runs at a
time under a root (``.publish/lock``); one opened inside another whose areas cover its own joins
it (``make publish`` lands its tables, scaling rows, claims and documents as one set).

Tests stop a publication at a chosen file: ``FLOCK_TORCHRL_PUBLISH_FAULT=<what>@<k>`` acts at the
k-th file landed once the stage is made (a rename: a write into the stage, the journal, a move),
``<what>`` one of ``SIGINT``, ``SIGTERM``, ``SIGKILL`` (sent to this process) or ``raise`` (a
``KeyboardInterrupt`` raised in place of that rename); ``count`` says how many there were.
"""

from __future__ import annotations

import filecmp
import json
import os
import shutil
import signal
import sys
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from ..config import ConfigError
from ..io import write_failure, write_text
from ..policies.checkpoint import CheckpointError
from ..world.spawn import SpawnError
from .signals import Stopped, say, stop_handlers

FOLDER = ".publish"
FAULT = "FLOCK_TORCHRL_PUBLISH_FAULT"
EXIT_ERROR = 2


class PublishError(Exception):
    """A publication refused or failed: one line (exit status 2)."""


def _key(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_ino, st.st_mtime_ns, st.st_size


def _files(folder: Path) -> dict[str, tuple[int, int, int]]:
    """Every file under ``folder`` (its path relative to it, POSIX) with its inode, mtime and size."""
    if not folder.is_dir():
        return {}
    return {p.relative_to(folder).as_posix(): _key(p) for p in sorted(folder.rglob("*"))
            if p.is_file() and not p.is_symlink() and FOLDER not in p.relative_to(folder).parts}


def _fsync_folder(folder: Path) -> None:
    with suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# ---------------------------------------------------------------------------- the fault hook (tests)
class _Fault:
    """``FLOCK_TORCHRL_PUBLISH_FAULT``: what to do at which rename, counted while a publication is open."""

    installed = False
    what: str | None = None
    at = 0
    count = 0

    @classmethod
    def arm(cls) -> None:
        spec = os.environ.get(FAULT, "")
        cls.what, cls.at, cls.count = None, 0, 0
        if not spec:
            return
        what, _, at = spec.partition("@")
        if spec != "count" and (what not in ("SIGINT", "SIGTERM", "SIGKILL", "raise") or not at.isdigit() or int(at) < 1):
            raise PublishError(f"{FAULT}={spec!r}: expected <SIGINT|SIGTERM|SIGKILL|raise>@<k >= 1>, or count")
        cls.what, cls.at = what, int(at or 0)
        if not cls.installed:
            sys.addaudithook(cls.hook)
            cls.installed = True

    @classmethod
    def disarm(cls) -> None:
        if cls.what == "count":
            say(f"{FAULT}: {cls.count} file(s) landed")
        cls.what = None

    @classmethod
    def hook(cls, event: str, args: Any) -> None:
        if event != "os.rename" or cls.what is None:
            return
        cls.count += 1
        if cls.count != cls.at:
            return
        what, cls.what = cls.what, None
        if what == "raise":
            raise KeyboardInterrupt(f"{FAULT}: raise@{cls.at}")
        os.kill(os.getpid(), getattr(signal, what))


# ---------------------------------------------------------------------------- signals held during the landing
@contextmanager
def held_signals() -> Iterator[list[int]]:
    """Stop signals are noted, not acted on, inside the block (in the main thread; elsewhere no
    handler can be set, and none runs)."""
    noted: list[int] = []
    with stop_handlers(lambda signum, frame: noted.append(signum)):
        yield noted


# ---------------------------------------------------------------------------- the publication
_OPEN: list["Publication"] = []
# What became of the last publication this process opened: "open", "discarded", "landed" (or None).
OUTCOME: dict[str, Any] = {"state": None, "name": "", "root": None}


def _root_of(areas: Sequence[Path]) -> Path:
    """The working directory when it holds every area, else the areas' deepest common folder."""
    cwd = Path.cwd()
    if all(a == cwd or cwd in a.parents for a in areas):
        return cwd
    folders = [a if a.is_dir() or not a.suffix else a.parent for a in areas]
    return Path(os.path.commonpath([str(f) for f in folders]))


def _land(root: Path, stage: Path, moves: Sequence[str], removes: Sequence[str]) -> int:
    """Move each staged file of ``moves`` onto its place under ``root`` (those already moved are
    skipped: a second pass finishes an interrupted one) and remove ``removes``; the count moved."""
    moved, folders = 0, set()
    for rel in moves:
        source, target = stage / rel, root / rel
        if not source.exists():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
        folders.add(target.parent)
        moved += 1
    for rel in removes:
        (root / rel).unlink(missing_ok=True)
        folders.add((root / rel).parent)
    for folder in folders:
        _fsync_folder(folder)
    return moved


def recover(root: str | os.PathLike, log: Callable[[str], None] = say) -> int:
    """Finish a publication under ``root`` that a killed process left half landed (its journal),
    or discard the stage of one that never reached its journal; the count of files moved.
    The caller holds the lock (:class:`Publication` calls it on opening)."""
    folder = Path(root) / FOLDER
    journal, stage = folder / "journal.json", folder / "stage"
    moved = 0
    if journal.is_file():
        plan = json.loads(journal.read_text())
        moved = _land(Path(root), stage, plan["moves"], plan["removes"])
        log(f"finished the publication {plan['name']!r} that was interrupted while it landed: {moved} more file(s) "
            f"moved, {len(plan['removes'])} removed; its set is now whole")
        journal.unlink()
    elif stage.exists():
        log(f"discarded the files an interrupted publication had staged in {stage} (nothing of it had landed)")
    if stage.exists():
        shutil.rmtree(stage)
    return moved


class Publication:
    """Files that land whole or not at all (the module's docstring says how).

    Args:
        name: what is published (said in messages and the journal).
        areas: folders or files the step writes (each copied into the stage first, so a step
            that reads and rewrites a folder sees its files).
        documents: files refreshed by ``refresh(self)`` just before the set lands (their
            staged copies written by it; documents that did not change are left alone).
        refresh: called once the step is done, before the journal is written.
        log: where its lines go.
    """

    def __init__(self, name: str, areas: Sequence[str | os.PathLike], documents: Sequence[str | os.PathLike] = (),
                 refresh: Callable[["Publication"], None] | None = None, log: Callable[[str], None] = say) -> None:
        self.name = name
        given = [Path(a).absolute() for a in areas]
        # an area inside another is part of it (checkpoints/<reading>/mixed in checkpoints/<reading>)
        self.areas = list(dict.fromkeys(a for a in given if not any(o in a.parents for o in given)))
        self.documents = [Path(d).absolute() for d in documents]
        self.refresh = refresh
        self.log = log
        self.root = _root_of(self.areas + self.documents)
        self.folder = self.root / FOLDER
        self.stage = self.folder / "stage"
        self.outer: Publication | None = None
        self.before: dict[str, tuple[int, int, int]] = {}
        self.landed: list[str] = []
        self.removed: list[str] = []
        self.done = False   # the set has landed
        self._lock: int | None = None

    # -- where files go
    def _relative(self, path: str | os.PathLike) -> str:
        absolute = Path(path).absolute()
        try:
            return absolute.relative_to(self.root).as_posix()
        except ValueError:
            raise PublishError(f"{path} lies outside the publication {self.name!r} (under {self.root})") from None

    def covers(self, path: str | os.PathLike) -> bool:
        absolute = Path(path).absolute()
        return any(absolute == a or a in absolute.parents for a in self.areas + self.documents)

    def staged(self, path: str | os.PathLike) -> Path:
        """Where ``path`` (a file or folder of an area or a document) is written during the step."""
        if self.outer is not None:
            return self.outer.staged(path)
        if not self.covers(path):
            raise PublishError(f"{path} is not part of the publication {self.name!r}: its areas are "
                               + ", ".join(self._relative(a) for a in self.areas))
        return self.stage / self._relative(path)

    def live(self, staged: str | os.PathLike) -> Path:
        """The place under the root of a staged path (what :meth:`staged` gave)."""
        if self.outer is not None:
            return self.outer.live(staged)
        return self.root / Path(staged).absolute().relative_to(self.stage)

    # -- opening
    def __enter__(self) -> "Publication":
        for other in reversed(_OPEN):
            if all(other.covers(p) for p in self.areas + self.documents):
                self.outer = other   # joins it: lands with it
                _OPEN.append(self)
                return self
        self._take_lock()
        try:
            recover(self.root, self.log)
            OUTCOME.update(state="open", name=self.name, root=self.root)
            for area in self.areas:
                self._mirror(area)
            self.before = _files(self.stage)
            _Fault.arm()
        except BaseException:
            shutil.rmtree(self.stage, ignore_errors=True)
            OUTCOME.update(state="discarded")
            self._release()
            raise
        _OPEN.append(self)
        return self

    def _take_lock(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.folder / "lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            import fcntl

            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except ImportError:   # no fcntl (Windows): one publication at a time is the user's care
            pass
        except OSError:
            os.close(fd)
            raise PublishError(f"another publication is under way under {self.root} (it holds {self.folder / 'lock'}); "
                               "let it finish, then run this one again") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock = fd

    def _release(self) -> None:
        if self._lock is None:
            return
        try:
            (self.folder / "lock").unlink(missing_ok=True)
        finally:
            os.close(self._lock)
            self._lock = None
        with suppress(OSError):
            self.folder.rmdir()   # only when empty: a journal left by a failure stays

    def _mirror(self, area: Path) -> None:
        target = self.stage / self._relative(area)
        if area.is_dir():
            shutil.copytree(area, target, copy_function=shutil.copy2, dirs_exist_ok=True, symlinks=True,
                            ignore=shutil.ignore_patterns(FOLDER))
        elif area.is_file():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(area, target)

    # -- closing
    def __exit__(self, kind: Any, exc: Any, tb: Any) -> None:
        _OPEN.remove(self)
        if self.outer is not None:
            return
        try:
            if kind is None:
                try:
                    self._commit()
                except BaseException:
                    if not self.done:
                        self._abandon()
                    raise
            else:
                self._abandon()
        finally:
            _Fault.disarm()
            self._release()

    def _abandon(self) -> None:
        journal = self.folder / "journal.json"
        if journal.is_file():   # an error while landing (not a signal: those wait): finish the set
            try:
                recover(self.root, self.log)
                OUTCOME.update(state="landed")
                return
            except Exception:   # the journal stays for the next publication to finish
                return
        shutil.rmtree(self.stage, ignore_errors=True)
        OUTCOME.update(state="discarded")

    def _changes(self) -> tuple[list[str], list[str]]:
        now = _files(self.stage)
        moves = []
        for rel, key in now.items():
            live = self.root / rel
            if self.before.get(rel) == key or (live.is_file() and filecmp.cmp(self.stage / rel, live, shallow=False)):
                continue
            moves.append(rel)
        removes = [rel for rel in self.before if rel not in now and (self.root / rel).exists()]
        return moves, removes

    def _commit(self) -> None:
        if self.refresh is not None:
            self.refresh(self)
        moves, removes = self._changes()
        journal = self.folder / "journal.json"
        with held_signals() as noted:
            if moves or removes:
                write_text(journal, json.dumps({"name": self.name, "moves": moves, "removes": removes}, indent=0))
                _land(self.root, self.stage, moves, removes)
                journal.unlink()
            shutil.rmtree(self.stage, ignore_errors=True)
            OUTCOME.update(state="landed")
            self.done = True
        self.landed, self.removed = moves, removes
        shown = ", ".join(moves[:6]) + (f" and {len(moves) - 6} more" if len(moves) > 6 else "")
        self.log(f"published {self.name}: " + (f"{len(moves)} file(s) changed ({shown})" if moves else "no file changed")
                 + (f", {len(removes)} removed" if removes else ""))
        if noted:   # a stop signal came while the set landed: act on it now, through the handler it had
            signal.raise_signal(noted[0])


# ---------------------------------------------------------------------------- a publishing command, as the apps run
ERRORS: tuple[type[BaseException], ...] = (ConfigError, CheckpointError, SpawnError, PublishError)


def stopped_line(signum: int) -> str:
    """The one line a publishing command prints when a stop signal ends it."""
    name = signal.Signals(signum).name
    state, what, root = OUTCOME["state"], OUTCOME["name"], OUTCOME["root"]
    if state == "landed":
        return f"stopped by {name}: the publication {what!r} had landed whole under {root}"
    if state in ("open", "discarded"):
        return (f"stopped by {name}: nothing of the publication {what!r} was published (its staged files are "
                f"discarded; every file under {root} is as it was)")
    return f"stopped by {name} before anything was published"


def entry(run: Callable[[], Any], noted: Sequence[int] = ()) -> int:
    """Run a publishing command as the apps run: this project's errors print ``error: <line>``
    (exit status 2); a stop signal prints one line (128 + the signal). ``noted``: signals a
    script noted while it imported the package. The handlers it sets are restored on return."""
    def stop(signum: int, frame: Any) -> None:
        raise Stopped(signum)

    with stop_handlers(stop):
        OUTCOME.update(state=None, name="", root=None)
        try:
            if noted:
                raise Stopped(noted[0])
            run()
            return 0
        except Stopped as exc:
            say(stopped_line(exc.signum))
            return 128 + exc.signum
        except KeyboardInterrupt:
            say(stopped_line(signal.SIGINT))
            return 128 + signal.SIGINT
        except ERRORS as exc:
            say(f"error: {' '.join(str(exc).split())}")
            return EXIT_ERROR
        except OSError as exc:
            if write_failure(exc) is None and not isinstance(exc, FileNotFoundError):
                raise
            say(f"error: {write_failure(exc) or exc}; nothing was published")
            return EXIT_ERROR


__all__ = ["ERRORS", "FAULT", "FOLDER", "OUTCOME", "Publication", "PublishError", "entry", "held_signals", "recover",
           "stopped_line"]

"""Atomic file writes (a temporary file in the target directory, then a rename) and whole output
folders (``StagedFolder``: a run's outputs staged beside the output folder and swapped in at once,
with a ``manifest.json`` of every file).

A crash or an error never leaves a half-written output (nor the temporary file), and an output
folder never mixes the files of two runs."""

from __future__ import annotations

import ctypes
import errno
import hashlib
import json
import os
import shutil
import stat
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import WarpShapeError, read_input_file

__all__ = ["atomic_write", "write_json", "atomic_target", "hold_lock", "release_lock", "finalize_permissions", "MANIFEST", "file_digest",
           "read_manifest", "manifest_problems", "creation_refused", "special_kind", "StagedFolder", "OutputError"]


class OutputError(WarpShapeError, OSError):
    """An output folder cannot be written: a file in its place, no write permission."""


def finalize_permissions(path) -> None:
    """Give a file made by mkstemp (mode 0600) the usual permissions for new files under the umask."""
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)


@contextmanager
def atomic_target(path):
    """Yield a temporary path next to ``path`` (same suffix) for a writer to fill; on success it
    replaces ``path``, on any error it is removed and ``path`` is left as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        finalize_permissions(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write(path, data: bytes | str) -> Path:
    """Write ``data`` (bytes, or str as UTF-8) to ``path`` atomically; returns the path."""
    with atomic_target(path) as tmp:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
    return Path(path)


def write_json(path, data) -> Path:
    """Write JSON (indented by 2) atomically; returns the path."""
    return atomic_write(path, json.dumps(data, indent=2) + "\n")


# ------------------------------------------------------------------------------------ whole output folders
MANIFEST = "manifest.json"
#: the largest manifest read (one a run writes is a few kB)
MAX_MANIFEST_BYTES = 16 * 2**20
ONE_BY_ONE = ("control", "export", "simulate")  # commands that wrote files one by one before they staged their sets
#: the manifest format of a set staged and swapped in whole (format 1: also the file-by-file lists of earlier versions)
STAGED_FORMAT = 2
MAX_FOREIGN_ENTRIES = 2000  # other files an output folder may hold (carried into each new set as hard links)
RENAME_EXCHANGE = 2  # linux/fs.h
AT_FDCWD = -100


def _lock_problem(path, what: str) -> str:
    return (f"the lock file {path} {what}; a run writes only a lock of its own there: move it away (or give "
            f"another --out)")


def _open_existing_lock(path, busy):
    """The descriptor of an existing lock file at ``path``, opened without following a link and checked
    to be a lock of a run (a regular file holding a process id, or nothing); None where it went away.
    Held by another process: raises ``busy(holder pid)``; a link, a folder or another file: ``OutputError``."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(_lock_problem(path, "is a symbolic link")) from None
        if exc.errno == errno.EISDIR:
            raise OutputError(_lock_problem(path, "is a folder")) from None
        raise OutputError(_lock_problem(path, f"cannot be opened ({exc.strerror})")) from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise OutputError(_lock_problem(path, "is a folder"))
        if not stat.S_ISREG(st.st_mode):
            raise OutputError(_lock_problem(path, "is not a regular file (a FIFO, a device or a socket)"))
        text = os.read(fd, 64).decode(errors="replace").strip() if st.st_size <= 64 else "?"
        if st.st_size > 64 or not (text == "" or text.isdigit()):
            raise OutputError(_lock_problem(path, "holds something else than a run's process id"))
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise busy(text or "?") from None
    except BaseException:
        os.close(fd)
        raise
    return fd


def hold_lock(path, busy) -> int:
    """Take the exclusive lock file ``path`` for this process and write its pid there; the lock goes with
    the process, even when it is killed. The file is created anew (``O_EXCL``, never through a link);
    a lock left by a run that ended (a process id, no holder) is removed first, and anything else at
    ``path`` (a link, a folder, a file of other content) is an ``OutputError``, left as it is. Held by
    another process: raises ``busy(holder pid)``. Returns the descriptor to give ``release_lock``."""
    import fcntl

    path = os.fspath(path)
    for _ in range(100):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY | os.O_NOFOLLOW, 0o644)
        except FileExistsError:
            stale = _open_existing_lock(path, busy)
            if stale is not None:  # a finished (or killed) run's lock, held by nobody: ours to remove
                try:
                    if os.stat(path, follow_symlinks=False).st_ino == os.fstat(stale).st_ino:
                        os.unlink(path)
                except FileNotFoundError:
                    pass
                finally:
                    os.close(stale)
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:  # another run took the file we made before we locked it
            os.close(fd)
            raise busy("?") from None
        try:
            if os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
                os.write(fd, str(os.getpid()).encode())
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)  # removed by a run that found it stale before we locked it: make a new one
    raise OutputError(_lock_problem(path, "keeps changing"))


def release_lock(path, fd: int) -> None:
    """Give up a lock of ``hold_lock`` and remove its file (a finished or failed run leaves none)."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    os.close(fd)


def file_digest(path) -> str:
    """The SHA-256 of a file, hex."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def read_manifest(folder) -> dict | None:
    """The ``manifest.json`` of an output folder, or None where there is none (or it is unreadable)."""
    try:
        data = json.loads(read_input_file(Path(folder) / MANIFEST, MANIFEST, max_bytes=MAX_MANIFEST_BYTES))
    except (OSError, ValueError, WarpShapeError):  # missing, unreadable, not a regular file, not JSON
        return None
    return data if isinstance(data, dict) and isinstance(data.get("files"), dict) else None


def manifest_problems(folder) -> list[str]:
    """What keeps ``folder`` from being the whole set its manifest lists: a missing manifest, a listed
    file missing or changed (size, SHA-256). Empty when the folder holds exactly what was written."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    if manifest is None:
        return [f"{folder} has no readable {MANIFEST}"]
    problems = []
    for name, info in manifest["files"].items():
        p = folder / name
        if not p.is_file():
            problems.append(f"{name} is listed in {MANIFEST} but missing")
        elif p.stat().st_size != info.get("bytes") or file_digest(p) != info.get("sha256"):
            problems.append(f"{name} differs from the {MANIFEST} record (size or SHA-256)")
    return problems


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directories in one step (Linux ``renameat2(RENAME_EXCHANGE)``); False where the
    system or file system cannot."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if fn(AT_FDCWD, os.fsencode(a), AT_FDCWD, os.fsencode(b), RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _link_tree(src: Path, dst: Path) -> None:
    """``dst`` as a copy of ``src`` made of hard links where the file system allows (copies otherwise)."""
    def link(s, d):
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)

    if src.is_dir() and not src.is_symlink():
        shutil.copytree(src, dst, symlinks=True, copy_function=link)
    elif src.is_symlink():
        os.symlink(os.readlink(src), dst)
    else:
        link(src, dst)


def _differs(path: Path, info: dict) -> bool:
    """Whether an entry a manifest lists is there and no longer the file it records (another size or
    SHA-256, or now a folder or a link)."""
    if not os.path.lexists(path):
        return False
    if path.is_symlink() or not path.is_file():
        return True
    return path.stat().st_size != info.get("bytes") or file_digest(path) != info.get("sha256")


def _listed(names, most: int = 5) -> str:
    """``names`` sorted, at most ``most`` of them, and how many more."""
    names = sorted(names)
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(names[:most]) + more


def creation_refused(folder) -> str | None:
    """Why no file can be made in ``folder`` (the system's reason), tried by making one and removing
    it again; None where one can. /proc and read-only mounts refuse here where ``os.access`` says
    yes to root."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".warp-shape-probe.", dir=folder)
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    os.close(fd)
    os.unlink(tmp)
    return None


def special_kind(path) -> str:
    """What ``path`` is, in words, for a message: "file", "folder", "FIFO (named pipe)", "device", "socket"."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return "file"
    return ("folder" if stat.S_ISDIR(mode) else "FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "socket" if stat.S_ISSOCK(mode)
            else "file")


def _probe_writable(folder: Path, what: str) -> None:
    reason = creation_refused(folder)
    if reason is not None:
        raise OutputError(f"{what} {folder} is not writable ({reason}); give --out a folder you can "
                          f"write to")


class StagedFolder:
    """The outputs of one run, written into ``<out>.partial`` and swapped into ``<out>`` whole.

    ``<out>`` only ever holds one whole set of outputs, listed with sizes and SHA-256 in its
    ``manifest.json``: the previous set until ``commit()`` exchanges the two folders in one rename
    (Linux; elsewhere two renames), the new set after. Files of the previous set that the new run
    does not write are gone with it; every other entry of ``<out>`` (not in its manifest) is carried
    over as hard links. ``check`` refuses, before any work, an ``<out>`` that is not a run's to
    replace: files and no manifest (sub-folders alone are carried), files no run wrote under a name
    ``owned`` says outputs of this kind have, files changed since the run wrote them. A symbolic link
    given as ``<out>`` is followed: its target is the folder checked and replaced, and the link stays.
    A run that is killed leaves ``<out>`` as it was and its finished part in ``<out>.partial``.
    """

    def __init__(self, out, owned=lambda name: False, command: str = "design"):
        self.command = command
        try:
            self.out = Path(os.path.abspath(os.path.expanduser(str(out))))
        except FileNotFoundError:  # the working folder was deleted under the command
            raise OutputError(f"--out {out}: the current folder no longer exists; cd into an existing folder or "
                              f"give --out as an absolute path") from None
        long = max(((len(os.fsencode(part)), part) for part in self.out.parts), default=(0, ""))
        if long[0] > 250:
            raise OutputError(f"--out {out}: the name {long[1][:40]}... is {long[0]} bytes long, more than a "
                              f"file system allows (255) with the run's staging suffix; give a shorter name")
        if not self.out.name:
            raise OutputError(f"--out {out} is the root folder; a run replaces its output folder as a whole: give "
                              f"it a folder of its own, e.g. --out out")
        self.link = None  # the symbolic link given as --out, where it was one
        if self.out.is_symlink():
            self.link, self.out = self.out, self.out.resolve()
        self.partial = self.out.with_name(self.out.name + ".partial")
        self.owned = owned
        self._begun = False
        self._lock_fd = None

    @property
    def shown(self) -> str:
        """``<out>`` as messages name it: the link given and the folder it points to, where it is a link."""
        return f"{self.link} (a link to {self.out})" if self.link is not None else str(self.out)

    def check(self) -> None:
        """A clear ``OutputError`` now, before any work, where the outputs could not be written or
        ``<out>`` is no folder of this command's to replace as a whole (``_check_own_folder``)."""
        if self.link is not None and not self.out.exists():
            raise OutputError(f"--out {self.link} is a symbolic link to {self.out}, which does not exist; give --out "
                              f"a folder (new or holding earlier outputs)")
        for p, what in ((self.out, "--out"), (self.partial, "the staging folder")):
            if p.exists() and not p.is_dir():
                raise OutputError(f"{what} {p} is a {special_kind(p)}, not a folder; give --out a folder (new or "
                                  f"holding earlier outputs)")
        parent = self.out.parent
        while not parent.exists():
            parent = parent.parent
        if not parent.is_dir():
            raise OutputError(f"--out {self.out}: {parent} is a {special_kind(parent)}, not a folder; give --out a "
                              f"path under a folder")
        _probe_writable(parent, "the folder holding --out")
        if self.out.is_dir():
            _probe_writable(self.out, "--out")
            self._check_own_folder()
        self._check_partial()

    def _check_own_folder(self) -> None:
        """``<out>`` is replaced as a whole: refuse the current folder (or one holding it), a folder
        holding files no run wrote and no manifest, files a run could replace that no run wrote, files
        changed since the run wrote them, and a folder of many other files (a project, a home folder),
        which would be copied into each set."""
        cwd = Path.cwd().resolve()
        if self.out == cwd or self.out in cwd.parents:
            raise OutputError(f"--out {self.shown} holds the current folder; a run replaces its output folder as a "
                              f"whole: give it a folder of its own, e.g. --out out")
        manifest = read_manifest(self.out)
        if manifest is None:
            foreign = [e.name for e in os.scandir(self.out) if self.owned(e.name) or e.name == MANIFEST
                       or self.command == "design" and not e.is_dir(follow_symlinks=False)]
            if foreign:
                raise OutputError(f"--out {self.shown} holds files no run wrote ({_listed(foreign)}) and no "
                                  f"{MANIFEST}; a run replaces its output set as a whole: move them out of --out, "
                                  f"or give --out an empty or new folder")
        else:
            self._check_command(manifest)
            self._check_listed(manifest)
        previous = set((manifest or {}).get("files", {}))
        count = 0
        for root, dirs, files in os.walk(self.out):
            if Path(root) == self.out:
                dirs[:] = [d for d in dirs if d not in previous]
                files = [f for f in files if f not in previous and f != MANIFEST]
            count += len(files) + len(dirs)
            if count > MAX_FOREIGN_ENTRIES:
                raise OutputError(f"--out {self.shown} holds more than {MAX_FOREIGN_ENTRIES} files that are not "
                                  f"outputs of a run; a run replaces its output folder as a whole (keeping such "
                                  f"files): give it a folder of its own, e.g. --out out")

    def _check_command(self, manifest: dict) -> None:
        """A set of another command (a design's, where this is an export) is never replaced by this one's."""
        theirs = manifest.get("command", "design")
        if theirs != self.command:
            sub = self.out / (self.command if self.command != "design" else "design")
            raise OutputError(f"--out {self.shown} holds a {theirs} run's set (its {MANIFEST} lists the files); "
                              f"a {self.command} run replaces its own set as a whole and would drop that one: give "
                              f"it a folder of its own, e.g. --out {sub}")

    def _check_listed(self, manifest: dict) -> None:
        """In a folder of a run: no file the run did not write under a name a run writes (the new set
        would replace it), no listed file changed since (the new set would drop the change). A list an
        earlier version wrote file by file (``ONE_BY_ONE``, format 1) may lag its files where that run
        was stopped between two: its own files then differ from the list, and are replaced."""
        listed = manifest["files"]
        legacy = manifest.get("command") in ONE_BY_ONE and manifest.get("format", 1) < STAGED_FORMAT
        named = [e.name for e in os.scandir(self.out) if e.name not in listed and e.name != MANIFEST
                 and self.owned(e.name)]
        if named:
            raise OutputError(f"--out {self.shown} holds files named as a run's outputs that no run wrote "
                              f"({_listed(named)}); the next run would replace them: move them out of --out, or "
                              f"give --out an empty or new folder")
        changed = [name for name, info in listed.items() if _differs(self.out / name, info)
                   and not (legacy and (self.out / name).is_file() and not (self.out / name).is_symlink())]
        if changed:
            raise OutputError(f"--out {self.shown}: {_listed(changed)} not as the run wrote (size or SHA-256 differs "
                              f"from {MANIFEST}); the next run would replace them: move them out of --out, or give "
                              f"--out an empty or new folder")

    def _check_partial(self) -> None:
        """``<out>.partial`` is removed when the run starts: only where it is a folder of a run's files
        (an earlier run's unfinished outputs, or links to files still in ``<out>``)."""
        if self.partial.is_symlink():
            raise OutputError(f"the staging folder {self.partial} is a symbolic link; a run writes its outputs "
                              f"there: remove the link (or give another --out)")
        if not self.partial.is_dir() or read_manifest(self.partial) is not None:
            return
        foreign = [e.name for e in os.scandir(self.partial) if not (self.owned(e.name) or e.name.startswith(".")
                                                                    or (self.out / e.name).exists())]
        if foreign:
            raise OutputError(f"the staging folder {self.partial} holds files no run wrote ({_listed(foreign)}); "
                              f"a run removes that folder when it starts: move them away, or give another --out")

    @contextmanager
    def writing(self):
        """Hold ``<out>``'s lock while the block runs (``lock``); where the block fails or is
        interrupted, the staging folder goes (``discard``) and ``<out>`` keeps its previous set; the
        lock is given up at the end in every case."""
        self.lock()
        try:
            yield self
        except BaseException:
            self.discard()
            raise
        finally:
            self.unlock()

    def lock(self) -> None:
        """Hold ``<parent>/.<out>.lock`` for the rest of the run: a second run into the same ``<out>``
        is refused (the lock goes with the process, even when it is killed)."""
        if self._lock_fd is not None:
            return
        if not self.out.parent.exists():
            self.out.parent.mkdir(parents=True)
        self._lock_fd = hold_lock(self._lock_path,
                                  lambda holder: OutputError(f"another run (process {holder}) is writing to "
                                                             f"{self.out}; wait for it to finish or give another --out"))

    @property
    def _lock_path(self) -> Path:
        return self.out.parent / f".{self.out.name}.lock"

    def unlock(self) -> None:
        """Let the next run into ``<out>`` start (done by ``commit`` and ``discard``); the lock file goes."""
        if self._lock_fd is not None:
            release_lock(self._lock_path, self._lock_fd)
            self._lock_fd = None

    @property
    def path(self) -> Path:
        """The staging folder, created (empty) on first use."""
        if not self._begun:
            if self.partial.exists():
                shutil.rmtree(self.partial)  # an earlier run's unfinished outputs
            self.partial.mkdir(parents=True)
            self._begun = True
        return self.partial

    def seal(self, complete: bool, **info) -> Path:
        """Write the staging folder's ``manifest.json``: every file in it with size and SHA-256."""
        folder = self.path
        files = {p.name: dict(bytes=p.stat().st_size, sha256=file_digest(p))
                 for p in sorted(folder.iterdir()) if p.is_file() and p.name != MANIFEST
                 and not p.name.startswith(".")}
        data = dict(format=STAGED_FORMAT, command=self.command, complete=bool(complete),
                    written=time.strftime("%Y-%m-%dT%H:%M:%S%z"), files=files)
        data.update(info)
        return atomic_write(folder / MANIFEST, json.dumps(data, indent=1) + "\n")

    def holds_complete_set(self) -> bool:
        """Whether ``<out>`` holds a finished run's outputs (its manifest says complete)."""
        m = read_manifest(self.out)
        return bool(m and m.get("complete"))

    def _carry_previous(self) -> None:
        """The previous set's files (listed in ``<out>``'s manifest, unchanged) that the staging folder
        does not hold, into it as hard links: they become part of the new set."""
        listed = (read_manifest(self.out) or {}).get("files", {}) if self.out.is_dir() else {}
        for name, info in listed.items():
            src = self.out / name
            if src.is_file() and not src.is_symlink() and not _differs(src, info) \
                    and not os.path.lexists(self.path / name):
                _link_tree(src, self.path / name)

    def _carry_foreign(self) -> None:
        """Every entry of ``<out>`` that its manifest does not list (checked by ``check``: none named
        as the new set's files are) into the staging folder, as hard links."""
        if not self.out.is_dir():
            return
        previous = set((read_manifest(self.out) or {}).get("files", {}))
        for entry in self.out.iterdir():
            name = entry.name
            if name == MANIFEST or name in previous or (self.partial / name).exists():
                continue
            _link_tree(entry, self.partial / name)

    def commit(self, complete: bool = True, keep_previous: bool = False, **info) -> Path:
        """Seal the staging folder and make it ``<out>`` in one step; the previous set is removed (with
        ``keep_previous``, its files the new run did not write again are carried into the new set)."""
        if keep_previous:
            self._carry_previous()
        self.seal(complete, **info)
        self._carry_foreign()
        if not self.out.exists():
            os.rename(self.partial, self.out)
        elif _exchange(self.partial, self.out):
            shutil.rmtree(self.partial)
        else:
            old = self.out.with_name(f".{self.out.name}.old-{os.getpid()}")
            os.rename(self.out, old)
            os.rename(self.partial, self.out)
            shutil.rmtree(old)
        self._begun = False
        self.unlock()
        return self.out

    def discard(self) -> None:
        """Remove the staging folder (a failed run leaves nothing behind)."""
        if self._begun:
            shutil.rmtree(self.partial, ignore_errors=True)
            self._begun = False
        self.unlock()

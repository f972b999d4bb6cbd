"""Where a command writes: one rule for every output path (``--out``, ``-o``), checked before
anything is computed.

The rule (``doc/errors.md``, "Output paths"):

* The output path must be absent or an empty directory; otherwise the command refuses in one line
  before it computes anything (``--out runs/a: not empty (12 entries): the output of an earlier
  dmf-sim sweep; pass --overwrite to replace it``).
* With ``--overwrite`` the command replaces what an earlier run of the *same* command wrote
  there, and only that: every command leaves a small manifest (:data:`MANIFEST`, naming the
  command and its files) beside its output. A path holding a file the manifest does not list, or
  written by another command, or with no manifest, is refused even with ``--overwrite``, naming
  one such file. The earlier files are removed just before the new ones are written (after the
  computation for most commands, so a run that fails keeps the earlier output; when the
  computation starts for those that write as they compute).
* A bare output *file* (``bag-recover -o OUT.mcap``) has no room for a manifest: the command
  says, from the file's content, whether it wrote it.
* Whether the path can be created and written is tried for real (a directory made and removed
  again, a temporary file written and removed) because :func:`os.access` says yes to root on a
  read-only file system; every :class:`OSError` (a name too long, a file where a directory
  should be, a read-only or full disk) is one :class:`~dmf_sim.core.errors.ConfigError` naming
  the option.

Usage in a command::

    dest = claim(args.out, 'sweep', overwrite=args.overwrite)     # before computing
    ...                                                             # compute
    with dest.writing() as out:                                     # the earlier output removed
        write files into out                                        # manifest written on exit
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import write_json

__all__ = ['MANIFEST', 'KINDS', 'DISK_MARGIN', 'DISK_RESERVE_BYTES', 'Destination', 'claim',
           'check_output_dir', 'check_free_space', 'free_bytes', 'human_bytes']

MANIFEST = '.dmf-sim-output.json'
"""The manifest a command leaves in its output directory: the command and the files it wrote."""
KINDS = ('dir', 'bag', 'file')
"""``dir``: a directory the command writes files into (created here); ``bag``: a directory the
bag writer creates itself (an empty one is accepted); ``file``: one file."""
DISK_MARGIN = 1.1                 # a long output needs its estimate plus 10 % ...
DISK_RESERVE_BYTES = 256 * 2**20  # ... plus this much left free on the disk afterwards


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def _exists(path: Path) -> bool:
    return path.exists() or path.is_symlink()


def _nearest_existing(path: Path) -> Path:
    probe = path.absolute()
    while not _exists(probe) and probe != probe.parent:
        probe = probe.parent
    return probe


def _entries(n: int) -> str:
    return f'{n} entr{"y" if n == 1 else "ies"}'


def check_output_dir(path: str | os.PathLike, option: str = '--out') -> Path:
    """Refuse, before anything is computed, an output directory that cannot be made or written
    (one-line :class:`ConfigError` naming ``option``): a path that exists and is not a
    directory, whose nearest existing ancestor is not a directory, or where creating the
    directory or a file in it fails. Tried for real; leaves nothing behind. Says nothing about
    what the directory holds (:func:`claim` does)."""
    if not os.fspath(path).strip():
        raise ConfigError(f'{option}: empty path')
    p = Path(path)
    verb = 'created'
    try:
        if _exists(p):
            if not p.is_dir():
                raise ConfigError(f'{option} {p}: exists and is not a directory')
            verb = 'written'
            _probe_file(p)
            return p
        ancestor = _nearest_existing(p)
        if not ancestor.is_dir():
            raise ConfigError(f'{option} {p}: cannot be created, {ancestor} is not a directory')
        _probe_mkdir(p)
    except OSError as exc:
        raise ConfigError(f'{option} {p}: cannot be {verb} ({_reason(exc)})') from None
    return p


def _probe_file(directory: Path) -> None:
    fd, name = tempfile.mkstemp(prefix='.dmf-sim-probe-', dir=directory)
    os.close(fd)
    os.unlink(name)


def _made_by(create: Callable[[], None], path: Path) -> None:
    """Call ``create`` (which makes ``path`` and maybe its parents), then remove what it made."""
    made = [q for q in (path, *path.parents) if not _exists(q)]
    try:
        create()
    finally:
        for q in made:
            with contextlib.suppress(OSError):
                q.unlink() if q.is_file() else q.rmdir()


def _probe_mkdir(path: Path) -> None:
    """Create ``path`` with its missing parents and a file in it, then remove them again."""
    def create() -> None:
        path.mkdir(parents=True)
        _probe_file(path)
    _made_by(create, path)


def _probe_new_file(path: Path) -> None:
    """Create the file ``path`` (and its missing parents), then remove them again."""
    def create() -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, 'x'):
            pass
    _made_by(create, path)


def _files(root: Path) -> list[str]:
    """Every file (and symlink) under ``root``, relative POSIX paths, the manifest left out."""
    out = []
    for here, dirs, files in os.walk(root):
        rel = Path(here).relative_to(root)
        for name in files + [d for d in dirs if os.path.islink(os.path.join(here, d))]:
            out.append((rel / name).as_posix())
    return sorted(f for f in out if f not in (MANIFEST, MANIFEST + '.tmp'))


def _read_manifest(root: Path) -> dict | None:
    """The manifest in ``root`` (None: there is none, or it cannot be read)."""
    try:
        data = json.loads((root / MANIFEST).read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


@dataclass
class Destination:
    """An output path that passed :func:`claim`; :meth:`writing` around the writing.

    path: the output path; command: the ``dmf-sim`` command writing it; option: its option name
    (for the messages); overwrite: replace the command's earlier output; kind: one of
    :data:`KINDS`; owned: for ``kind='file'``, whether an existing file is this command's;
    resume: the command continues its earlier output there (design studies' ``--resume``)."""

    path: Path
    command: str
    option: str = '--out'
    overwrite: bool = False
    kind: str = 'dir'
    owned: Callable[[Path], bool] | None = None
    resume: bool = False
    _created: bool = field(default=False, repr=False)

    def error(self, what: str) -> ConfigError:
        return ConfigError(f'{self.option} {self.path}: {what}')

    # ---- the check, before anything is computed ------------------------------------------------
    def check(self, resume_option: str | None = None) -> None:
        """Refuse (one line) a path the command may not write (module docstring);
        ``resume_option`` (e.g. ``--resume``) is named in the message of a directory holding
        the command's earlier output."""
        try:
            if self.kind == 'file':
                self._check_file()
            else:
                check_output_dir(self.path, self.option)
                self._earlier(resume_option)
        except ConfigError:
            raise
        except OSError as exc:
            raise self.error(f'cannot be used ({_reason(exc)})') from None

    def _check_file(self) -> None:
        p = self.path
        if _exists(p):
            if p.is_dir():
                raise self.error('is a directory; give a file name')
            if not self.overwrite:
                raise self.error("exists; pass --overwrite to replace this command's earlier "
                                 'output')
            if self.owned is None or not self.owned(p):
                raise self.error(f'was not written by dmf-sim {self.command}; not overwriting '
                                 'it')
            _probe_file(p.parent if str(p.parent) else Path('.'))
            return
        ancestor = _nearest_existing(p.parent)
        if not ancestor.is_dir():
            raise self.error(f'cannot be created, {ancestor} is not a directory')
        try:
            _probe_new_file(p)
        except OSError as exc:
            raise self.error(f'cannot be created ({_reason(exc)})') from None

    def _earlier(self, resume_option: str | None = None) -> list[str]:
        """The files of the command's earlier output in the directory, to be replaced (none:
        it is absent or empty, or ``resume``); anything else refused in one line."""
        p = self.path
        if not p.is_dir():
            return []
        entries = sorted(os.listdir(p))
        if not entries:
            return []
        manifest = _read_manifest(p)
        present = _files(p)
        first = present[0] if present else entries[0]
        if manifest is not None and manifest.get('command') not in (None, self.command):
            raise self.error(f'holds the output of dmf-sim {manifest["command"]} (e.g. '
                             f'{first}), not of dmf-sim {self.command}; choose another '
                             f'{self.option}')
        if self.resume:
            return []
        if manifest is None:
            if not self.overwrite:
                raise self.error(f'not empty ({_entries(len(entries))}, e.g. {first}) and not '
                                 f'the output of an earlier dmf-sim {self.command}; choose a '
                                 'new or empty directory')
            raise self.error(f'holds {first}, which dmf-sim {self.command} did not write (no '
                             f'readable {MANIFEST} there); not overwriting it')
        if not self.overwrite:
            also = f' or {resume_option} to continue it' if resume_option else ''
            n = len(present)
            raise self.error(f'not empty ({n} file{"s" if n != 1 else ""} of an earlier dmf-sim '
                             f'{self.command}); pass --overwrite to replace them{also}')
        listed = set(manifest.get('files') or [])
        for f in present:
            if f not in listed:
                raise self.error(f'holds {f}, which the earlier dmf-sim {self.command} did not '
                                 'write; not overwriting it (remove it or choose another '
                                 f'{self.option})')
        return present

    def replaced_bytes(self) -> int:
        """Bytes of the earlier output :meth:`writing` will remove (``overwrite``)."""
        if not self.overwrite:
            return 0
        if self.kind == 'file':
            return self.path.stat().st_size if self.path.is_file() else 0
        return sum((self.path / f).lstat().st_size for f in self._earlier())

    # ---- writing ---------------------------------------------------------------------------
    @contextlib.contextmanager
    def writing(self) -> Iterator[Path]:
        """Remove the command's earlier output (``overwrite``: checked again now, after the
        computation), create the directory (``kind`` dir), yield the path; on the way out, also
        after an error or Ctrl-C, write the manifest of the files now there (none: a directory
        made here is removed again). An OSError writing into the path is one line naming the
        option."""
        p = self.path
        try:
            if self.kind == 'file':
                if self.overwrite and p.is_file() and self.owned is not None and self.owned(p):
                    p.unlink()
            else:
                self._remove(self._earlier())
                self._created = not _exists(p)
                if self.kind == 'dir':
                    p.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise self.error(f'cannot be written ({_reason(exc)})') from None
        try:
            yield p
        except OSError as exc:
            name = exc.filename if isinstance(exc.filename, str) else None
            if name is None or not _inside(Path(name), p):
                raise
            raise self.error(f'cannot write {name} ({_reason(exc)})') from None
        finally:
            if self.kind != 'file':
                self._finish()

    def _remove(self, files: list[str]) -> None:
        """Remove ``files`` (relative to the path), the manifest, and the folders that held
        them once they are empty."""
        root = self.path
        if not files:
            return
        folders = set()
        for rel in files:
            (root / rel).unlink(missing_ok=True)
            folders.update(Path(rel).parents)
        (root / MANIFEST).unlink(missing_ok=True)
        for folder in sorted(folders - {Path('.')}, key=lambda f: -len(f.parts)):
            if not os.listdir(root / folder):
                os.rmdir(root / folder)

    def _finish(self) -> None:
        p = self.path
        if not p.is_dir():
            return
        files = _files(p)
        if not files:
            (p / MANIFEST).unlink(missing_ok=True)
            if self._created and not os.listdir(p):
                p.rmdir()
            return
        from dmf_sim import __version__
        tmp = p / (MANIFEST + '.tmp')
        write_json(tmp, {'command': self.command, 'version': __version__, 'files': files})
        os.replace(tmp, p / MANIFEST)


def _inside(path: Path, root: Path) -> bool:
    try:
        path.absolute().relative_to(root.absolute())
    except ValueError:
        return False
    return True


def claim(path: str | os.PathLike, command: str, *, option: str = '--out',
          overwrite: bool = False, kind: str = 'dir', resume: bool = False,
          resume_option: str | None = None,
          owned: Callable[[Path], bool] | None = None) -> Destination:
    """Check the output ``path`` of ``command`` under the one rule (module docstring) before
    anything is computed; returns the :class:`Destination` to write it with.

    ``resume``: the command continues its earlier output there (what it holds is the command's
    to check); ``resume_option``: the option that does, named in the message."""
    if kind not in KINDS:
        raise ValueError(f'kind must be one of {KINDS}, got {kind!r}')
    if not os.fspath(path).strip():
        raise ConfigError(f'{option}: empty path')
    dest = Destination(Path(path), command, option, overwrite, kind, owned, resume)
    dest.check(resume_option)
    return dest


def free_bytes(path: str | os.PathLike) -> int:
    """Free bytes (for this user) on the disk ``path`` is or would be on."""
    return shutil.disk_usage(_nearest_existing(Path(path))).free


def human_bytes(n: float) -> str:
    for unit in ('B', 'kB', 'MB', 'GB', 'TB'):
        if abs(n) < 1000 or unit == 'TB':
            return f'{n:.3g} {unit}'
        n /= 1000
    return f'{n:.3g} TB'


def check_free_space(path: str | os.PathLike, need_bytes: float, what: str, advice: str, *,
                     freed_bytes: int = 0) -> None:
    """Refuse (one line) an output of about ``need_bytes`` that would not fit on the disk of
    ``path`` with :data:`DISK_MARGIN` and :data:`DISK_RESERVE_BYTES` to spare; ``freed_bytes``:
    what the earlier output it replaces frees."""
    free = free_bytes(path)
    if need_bytes * DISK_MARGIN + DISK_RESERVE_BYTES > free + freed_bytes:
        also = f' (+ {human_bytes(freed_bytes)} of the output it replaces)' if freed_bytes else ''
        raise ConfigError(f'{path}: {what} would take about {human_bytes(need_bytes)}, '
                          f'{human_bytes(free)} free on that disk{also}; {advice}')

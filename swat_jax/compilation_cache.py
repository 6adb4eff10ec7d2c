"""JAX's persistent compilation cache and the program cache, switched on by :func:`enable_caches`.

MJX programs take tens of seconds to compile; the caches make the second run of any command start
in seconds. Every command (``python -m swat_jax.train``, ``eval``, ...) calls :func:`enable_caches` first;
importing swat_jax changes no setting of JAX, so a program that imports the library keeps its own, and
calls ``swat_jax.enable_caches()`` to get the commands' caches. The cache lives in ``$SWAT_JAX_CACHE_DIR`` (default ``~/.cache/swat_jax/jax``, per user);
``SWAT_JAX_COMPILATION_CACHE=0`` turns it off. An explicit ``JAX_COMPILATION_CACHE_DIR`` wins.

The cache is keyed by the lowered program, and JAX's in-memory caches of traced functions change how a
program lowers after others in the same process (the training iteration, lowered a second time from a
new ``Experiment``, gains a duplicated helper function): :func:`lower_built_afresh` lowers the large
programs as a fresh process would, so a second run in one process (tests, notebooks, a resume
on another device layout) finds the first run's programs in the cache.

JAX's cache skips XLA's compile, not the tracing and lowering before it (half a warm start of an
Animal-Walkers run). :func:`compile_cached` keeps the run's large programs whole, compiled, in
``programs/`` of the same directory, keyed by what they are traced from (the run's config, its bodies'
compiled MuJoCo models, the arguments' shapes and placement) and by this package's source, the
libraries' versions, JAX's settings and ``XLA_FLAGS``: a second start of the same run loads them without
tracing, and within one process a program asked for again (a second evaluation) is returned at once.
The programs least recently saved or loaded are deleted once ``programs/`` outgrows
``$SWAT_JAX_PROGRAM_CACHE_GIB`` (default 2 GiB; an Animal-Walkers iteration takes about 7 MB).
"""

from __future__ import annotations

import collections
import functools
import hashlib
import importlib.metadata
import os
import pickle
import re
import sys
import time
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

DISABLE_VARIABLE = "SWAT_JAX_COMPILATION_CACHE"
DIRECTORY_VARIABLE = "SWAT_JAX_CACHE_DIR"
MIN_COMPILE_SECONDS = 1.0
"""Programs that compile faster than this are not worth a disk entry."""
PROGRAMS = "programs"
"""The subdirectory of the cache directory that holds :func:`compile_cached`'s programs."""
PORTABLE_CUSTOM_CALL = re.compile(r"lapack_\w+_ffi|swat_jax_c_physics")
"""The custom calls a program loaded in another process can make: LAPACK's (which
:func:`_initialize_lapack` sets up) and C physics' (which every process that builds a C-physics body
registers, :mod:`swat_jax.envs.named_callback`). Programs that call anything else (Warp's kernels, Python
callbacks, a GPU library) are not saved."""
SIZE_VARIABLE = "SWAT_JAX_PROGRAM_CACHE_GIB"
DEFAULT_PROGRAMS_GIB = 2.0
"""The program cache's size limit, GiB, unless ``$SWAT_JAX_PROGRAM_CACHE_GIB`` sets another."""
IN_MEMORY_PROGRAMS = 8
"""How many programs a process keeps (:data:`_in_memory`; an Animal-Walkers iteration is about 7 MB saved)."""
LIBRARIES = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "flax", "optax", "numpy", "warp-lang")
"""The installed distributions whose versions key the program cache (besides this package's source)."""


class CacheSettingError(ValueError):
    """A cache setting (an environment variable) that cannot be used; the message names it and the fix."""


def cache_directory() -> Path | None:
    """Where compiled programs are cached, or None when the cache is turned off."""
    if os.environ.get(DISABLE_VARIABLE, "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    if "JAX_COMPILATION_CACHE_DIR" in os.environ:
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "swat_jax" / "jax"
    return Path(os.environ.get(DIRECTORY_VARIABLE, default)).expanduser()


_programs_enabled = False
"""Whether :func:`compile_cached` keeps programs: set by :func:`enable_caches`."""
_in_memory: collections.OrderedDict[Path, Any] = collections.OrderedDict()
"""The programs :func:`compile_cached` returned in this process, by file path, most recently used last: a
second call for a program returns it without tracing, lowering or reading it back, even when it is not on
disk (a program JAX's own cache held is not saved)."""


def enable_caches() -> Path | None:
    """Turn on JAX's persistent compilation cache and the program cache (:func:`compile_cached`) in the cache
    directory, before or after jax is imported; returns the directory, or None when
    ``$SWAT_JAX_COMPILATION_CACHE`` turns the caches off. The commands call it; a library user calls it once."""
    global _programs_enabled
    directory = cache_directory()
    if directory is None:
        return None
    _programs_enabled = True
    settings = {
        "jax_compilation_cache_dir": str(directory),
        "jax_persistent_cache_min_compile_time_secs": MIN_COMPILE_SECONDS,
    }
    for name, value in settings.items():
        if name.upper() in os.environ:
            continue  # the user's JAX_* variable wins
        if "jax" in sys.modules:
            sys.modules["jax"].config.update(name, value)
        else:
            os.environ[name.upper()] = str(value)
    return directory


def lower_built_afresh(build: Callable[[], Any], *args: Any) -> Any:
    """``build().lower(*args)`` (``build()`` a ``jax.jit`` result), built after clearing JAX's in-memory trace
    and lowering caches: the ``jax.stages.Lowered`` program, and so its persistent-cache key, is the one a
    fresh process lowers. A build that traces the same function on the way (``jax.eval_shape`` for its
    output shardings) leaves that trace in the cache for the lowering, so the function is traced once."""
    import jax

    jax.clear_caches()
    return build().lower(*args)


def compile_cached(
    name: str, build: Callable[[], Any], args: Sequence[Any], recipe: Sequence[Any] | None
) -> Any:
    """The ``jax.stages.Compiled`` program of ``build()`` (a ``jax.jit`` result) for ``args``: loaded from the
    program cache when a program of the same name, recipe and arguments was compiled before by the same
    source, libraries and settings; else lowered with :func:`lower_built_afresh`, compiled and saved.
    Before :func:`enable_caches` (or with the caches turned off) it only lowers and compiles: JAX's
    in-memory caches, which :func:`lower_built_afresh` clears for the whole process, stay as they are.

    Args:
        name: the file name's prefix (``iteration``, ``evaluation``...).
        build: makes the jitted function; called only when the program is not in the cache.
        args: the arguments the program will be called with; their tree, shapes, dtypes and shardings key it.
        recipe: everything else the traced function depends on, as values with a deterministic ``repr``
            (frozen configs, tuples) or bytes: with this package's source and the settings, it must determine
            the program. None for programs that cannot be loaded in another process (calls into kernels
            registered by this one, such as MuJoCo Warp's): compiled every time,
            never saved, and lowered with JAX's in-memory caches as they are (no cache could meet a fresh
            lowering of it, and clearing them would make the process trace its other functions again).

    Runs over several hosts compile every time too: each host's program is its part of one program.
    """
    import jax

    directory = cache_directory() if _programs_enabled else None
    if directory is None or recipe is None:  # no cache to meet: JAX's in-memory caches are left as they are
        return build().lower(*args).compile()
    if jax.process_count() > 1:
        return lower_built_afresh(build, *args).compile()
    limit = program_cache_limit()
    path = directory / PROGRAMS / f"{name}-{_program_key(name, recipe, args)}"
    compiled = _in_memory.get(path) or _load_program(path)
    if compiled is None:
        hits = _persistent_cache_hits()
        compiled = lower_built_afresh(build, *args).compile()
        # JAX's cache held it: an executable it loaded saves without some of its kernels (jax 0.10.2).
        if _persistent_cache_hits() == hits:
            _save_program(compiled, path, limit)
    _keep_in_memory(path, compiled)
    return compiled


def _keep_in_memory(path: Path, compiled: Any) -> None:
    _in_memory[path] = compiled
    _in_memory.move_to_end(path)
    while len(_in_memory) > IN_MEMORY_PROGRAMS:
        _in_memory.popitem(last=False)


def compiled_at_first_call(
    name: str, build: Callable[[], Any], recipe: Sequence[Any] | None
) -> Callable[..., Any]:
    """:func:`compile_cached` for the arguments of the first call; later calls run that program."""
    compiled = None

    def call(*args: Any) -> Any:
        nonlocal compiled
        if compiled is None:
            compiled = compile_cached(name, build, args, recipe)
        return compiled(*args)

    return call


def _program_key(name: str, recipe: Sequence[Any], args: Sequence[Any]) -> str:
    """SHA-256 of the program's name, recipe and argument signature, and of everything else that shapes a
    compiled program: this package's source, the libraries' versions, JAX's settings (less the cache's
    own), ``XLA_FLAGS`` and the devices."""
    import jax

    digest = hashlib.sha256()

    def add(part: Any) -> None:
        data = part if isinstance(part, bytes) else repr(part).encode()
        digest.update(len(data).to_bytes(8, "little") + data)

    add(name)
    for part in recipe:
        add(part)
    # Leaf paths, not the tree's str: static fields (MJX's numpy arrays) print with their addresses.
    for path, leaf in jax.tree_util.tree_flatten_with_path(args)[0]:
        sharding = getattr(leaf, "sharding", None)
        mesh = getattr(sharding, "mesh", None)
        devices = getattr(mesh, "device_ids", None)
        add(
            (
                jax.tree_util.keystr(path),
                str(jax.typeof(leaf)),
                repr(sharding),
                repr(devices),
                getattr(leaf, "committed", None),
            )
        )
    add(_source_and_libraries())
    settings = {
        key: value
        for key, value in jax.config.values.items()
        if not key.startswith(
            ("jax_compilation_cache", "jax_persistent_cache", "jax_enable_compilation_cache")
        )
    }
    add(sorted(settings.items(), key=lambda item: item[0]))
    add(os.environ.get("XLA_FLAGS", ""))
    add([(device.platform, device.device_kind, device.id, device.process_index) for device in jax.devices()])
    return digest.hexdigest()


@functools.cache
def _source_and_libraries() -> str:
    """SHA-256 of every Python file of this package (path and contents) and the libraries' versions."""
    package = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes() + b"\0")
    for library in LIBRARIES:
        try:
            version = importlib.metadata.version(library)
        except importlib.metadata.PackageNotFoundError:
            version = "absent"
        digest.update(f"{library}=={version}\0".encode())
    digest.update(sys.version.encode())
    return digest.hexdigest()


def _load_program(path: Path) -> Any:
    """The compiled program saved at ``path``, or None if there is none or it cannot be loaded."""
    import jax
    from jax.experimental import serialize_executable

    if not path.exists():
        return None
    _initialize_lapack()
    try:
        payload, in_tree, out_tree, device_ids = pickle.loads(zlib.decompress(path.read_bytes()))
        devices = {device.id: device for device in jax.devices()}
        compiled = serialize_executable.deserialize_and_load(
            payload, in_tree, out_tree, execution_devices=[devices[index] for index in device_ids]
        )
    except Exception as error:  # a truncated or foreign file: compiled again and overwritten
        print(f"warning: ignoring the unreadable cached program {path} ({error!r})", file=sys.stderr)
        return None
    _mark_used(path)
    return compiled


def _mark_used(path: Path) -> None:
    """Set ``path``'s modification time to now, in nanoseconds: the kernel stamps writes and ``touch`` with
    a clock that ticks every few milliseconds, so a program saved and another loaded within one tick would
    tie, and eviction would pick between them by name."""
    now = time.time_ns()
    os.utime(path, ns=(now, now))


def _save_program(compiled: Any, path: Path, limit: int) -> None:
    """``compiled`` written to ``path`` atomically, then the least recently used programs evicted down to
    ``limit`` bytes; programs JAX cannot serialize, or that make custom calls other than
    :data:`PORTABLE_CUSTOM_CALL`'s, are not saved."""
    from jax.experimental import serialize_executable

    targets = set(re.findall(r'custom_call_target="([^"]+)"', compiled.as_text()))
    if not all(PORTABLE_CUSTOM_CALL.fullmatch(target) for target in targets):
        return
    try:
        data = zlib.compress(
            pickle.dumps((*serialize_executable.serialize(compiled), _device_ids(compiled))), 1
        )
    except (ValueError, NotImplementedError, pickle.PicklingError, TypeError):
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f"{path.name}.{os.getpid()}.partial")
    partial.write_bytes(data)
    os.replace(partial, path)
    _mark_used(path)
    _evict_least_recently_used(path.parent, limit, keep=path)


def program_cache_limit() -> int:
    """The program cache's size limit in bytes, from ``$SWAT_JAX_PROGRAM_CACHE_GIB``; CacheSettingError if
    that is not a size (commands check it before they write anything)."""
    text = os.environ.get(SIZE_VARIABLE, str(DEFAULT_PROGRAMS_GIB))
    try:
        gib = float(text)
    except ValueError:
        gib = -1.0
    if not gib >= 0:
        raise CacheSettingError(
            f"{SIZE_VARIABLE}={text!r} is not a size in GiB: set it to a number such as 0.5 or 4, "
            f"or unset it for the default {DEFAULT_PROGRAMS_GIB:g} GiB"
        )
    return int(gib * 2**30)


def _evict_least_recently_used(directory: Path, limit: int, keep: Path) -> None:
    """Delete the programs of ``directory`` least recently saved or loaded (file modification time) until
    the rest take at most ``limit`` bytes; ``keep`` (the program just saved) always stays."""
    entries = []
    for path in directory.iterdir():
        if path.name.endswith(".partial"):
            continue
        try:
            status = path.stat()
        except FileNotFoundError:  # evicted by another process meanwhile
            continue
        entries.append((status.st_mtime_ns, status.st_size, path))
    total = 0
    for _, size, path in sorted(entries, key=lambda entry: (entry[2] != keep, -entry[0])):
        total += size
        if total > limit and path != keep:
            path.unlink(missing_ok=True)


def _device_ids(compiled: Any) -> list[int]:
    """The ids of the devices ``compiled`` runs on, in its mesh's order (a loaded program runs on the
    devices it is given: by default every device). ValueError if its outputs have neither a mesh nor a
    single device."""
    import jax

    sharding = jax.tree_util.tree_leaves(compiled.output_shardings)[0]
    mesh = getattr(sharding, "mesh", None)
    devices = list(mesh.devices.flat) if mesh is not None else list(sharding.device_set)
    if mesh is None and len(devices) != 1:
        raise ValueError(f"no device order for {sharding}")
    return [device.id for device in devices]


@functools.cache
def _initialize_lapack() -> None:
    """Set up LAPACK's kernels for the CPU. JAX does it when it first lowers a linear-algebra operation;
    a loaded program calls them without lowering anything (and crashes if they are not set up)."""
    import jax
    import jax.numpy as jnp

    jax.jit(jnp.linalg.cholesky).trace(jnp.eye(2)).lower(lowering_platforms=("cpu",))


def _persistent_cache_hits() -> int:
    """How many programs this process has loaded from JAX's persistent cache so far."""
    return _persistent_cache_hit_counter()[0]


@functools.cache
def _persistent_cache_hit_counter() -> list[int]:
    """A one-element list that JAX's cache-hit events increment, from the first call on."""
    import jax

    counter = [0]

    def listen(event: str, **_: Any) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            counter[0] += 1

    jax.monitoring.register_event_listener(listen)
    return counter

"""The elastic mode's joint reference table (:func:`controller.elastic.joint_reference_on_grid`)
compiled: ``ik_table.cpp`` runs :meth:`controller.joint_reference.CartesianToJoint.solve` knot
after knot with pinocchio's own template code (compiled from the headers the ``pin`` wheel
ships) and scipy's LAPACK routines, the same operations in the same order, so the table is the
Python loop's bit for bit (``tests/controller/test_ik_table.py``). Knots the fast path does
not accept go back to Python (:func:`solve_table`), one at a time.

Built through the native layer (:mod:`native`, C++ with ``-ffp-contract=off``); None when it
cannot be built (no C++ compiler, no pinocchio or Eigen headers, a joint type other than
revolute about x, y or z): the Python loop then runs, with the same numbers.
"""
from __future__ import annotations

import ctypes
from pathlib import Path
from typing import Any

import numpy as np

import native

SOURCE = Path(__file__).with_name("ik_table.cpp")
#: The pin wheel's own configuration of boost.mpl (its joint variant has more than 20 types).
CXXFLAGS: tuple[str, ...] = ("-O2", "-shared", "-fPIC", "-std=c++17", "-ffp-contract=off", "-w",
                             "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", "-DBOOST_MPL_LIMIT_LIST_SIZE=30",
                             "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30", "-DBOOST_FUSION_INVOKE_MAX_ARITY=12",
                             "-Wl,--no-as-needed", "-lstdc++")
_JOINT_TYPES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


def include_dirs() -> list[Path]:
    """pinocchio's headers (the pin wheel's prefix) and Eigen's (casadi's copy, else the system's)."""
    import pinocchio

    found = []
    for parent in Path(pinocchio.__file__).resolve().parents:
        if (parent / "include" / "pinocchio" / "multibody.hpp").is_file():
            found.append(parent / "include")
            break
    else:
        raise native.NativeBuildError("compiled IK table: pinocchio's C++ headers not found next to the pin wheel")
    candidates = []
    try:
        import casadi

        candidates.append(Path(casadi.__file__).resolve().parent / "include" / "eigen3")
    except ImportError:
        pass
    candidates += [Path("/usr/include/eigen3"), Path("/usr/local/include/eigen3")]
    eigen = next((c for c in candidates if (c / "Eigen" / "Core").is_file()), None)
    if eigen is None:
        raise native.NativeBuildError("compiled IK table: Eigen's headers not found (casadi/include/eigen3, "
                                      "/usr/include/eigen3)")
    return [*found, eigen]


def _capsule_pointer(capi: dict, name: str) -> int:
    capsule = capi[name]
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
    get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
    get_pointer.restype, get_pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    return int(get_pointer(capsule, get_name(capsule)))


def _build_and_load(cached_only: bool = False) -> ctypes.CDLL:
    library = native.load_ctypes(native.build("ik_table", [SOURCE], cflags=CXXFLAGS, include_dirs=include_dirs(),
                                              cached_only=cached_only))
    library.ik_table_new.restype = ctypes.c_void_p
    library.ik_table_new.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int,
                                     ctypes.c_void_p] + [ctypes.c_void_p] * 4
    library.ik_table_free.argtypes = [ctypes.c_void_p]
    library.ik_table_run.restype = ctypes.c_longlong
    library.ik_table_run.argtypes = ([ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong] + [ctypes.c_void_p] * 6
                                     + [ctypes.c_double] * 3 + [ctypes.c_void_p] * 2 + [ctypes.c_double])
    return library


_loaded: list = []  # [library or None] once tried in this process


def load(build: bool = True) -> ctypes.CDLL | None:
    """The compiled table library, or None (see the module docstring). ``build=False`` (a run):
    only when it is in the cache already - compiling pinocchio's templates takes about 40 CPU-s,
    far more than the 0.8 CPU-s the table saves a run, so a run does not wait for it; ``python
    -m cosim build`` builds it at install, and the Python loop gives the same numbers (said
    once). Under ``COSIM_NATIVE=require`` it is built either way."""
    if _loaded:
        return _loaded[0]
    if native.mode() == "off":
        return None
    if build or native.mode() == "require":
        library = native.optional("compiled IK table", _build_and_load)
    else:
        try:
            library = _build_and_load(cached_only=True)
        except (native.NativeBuildError, OSError) as exc:
            native.fallback("compiled IK table", exc)
            library = None
        if library is None:
            return None  # not cached (yet): tried again by the next caller that may build
    _loaded.append(library)
    return library


def _placement(M: Any) -> np.ndarray:
    return np.concatenate([np.asarray(M.rotation, dtype=float).reshape(9), np.asarray(M.translation, dtype=float)])


def solve_table(ik: Any, reference: Any, out: np.ndarray, build: bool = True) -> bool:
    """Fill ``out`` (3, n, 6) with q, qd, qdd of ``reference`` (a TcpTrajectory) on its knots
    by ``ik`` (a reset :class:`controller.joint_reference.CartesianToJoint`), compiled; the
    knots the compiled fast path hands back are solved by ``ik.solve``. False (``out``
    untouched) when the compiled table is not available for this model (``build``: see
    :func:`load`)."""
    from controller.joint_reference import SINGULARITY_TOLERANCE

    library = load(build)
    if library is None:
        return False
    model = ik.model
    types = [_JOINT_TYPES.get(model.joints[i].shortname()) for i in range(1, model.njoints)]
    if None in types or model.nv != 6 or model.njoints != 7:
        return False
    frame = model.frames[ik.frame_id]
    parents = np.array([model.parents[i] for i in range(1, model.njoints)], dtype=np.intc)
    placements = np.ascontiguousarray([_placement(model.jointPlacements[i]) for i in range(1, model.njoints)])
    frame_placement = _placement(frame.placement)
    joint_types = np.array(types, dtype=np.intc)
    import scipy.linalg.cython_blas as blas
    import scipy.linalg.cython_lapack as lapack

    pointers = [_capsule_pointer(lapack.__pyx_capi__, name) for name in ("dgesv", "dgetrf", "dgetrs")]
    pointers.append(_capsule_pointer(blas.__pyx_capi__, "ddot"))
    handle = library.ik_table_new(len(types), joint_types.ctypes.data, parents.ctypes.data, placements.ctypes.data,
                                  int(frame.parentJoint), frame_placement.ctypes.data, *pointers)
    if not handle:
        return False
    try:
        n, h = reference.grid.n, reference.grid.dt
        rotations = np.ascontiguousarray(reference.rotation, dtype=float)
        positions = np.ascontiguousarray(reference.position, dtype=float)
        twists = np.ascontiguousarray(reference.twist, dtype=float)
        accelerations = np.ascontiguousarray(reference.acceleration, dtype=float)
        if rotations.shape != (n, 3, 3) or positions.shape != (n, 3) or out.shape != (3, n, 6) \
                or not out.flags.c_contiguous:
            return False
        state = np.concatenate([ik.q, ik.qd, ik.qdd])
        lower = np.array(ik._lower, dtype=float)
        upper = np.array(ik._upper, dtype=float)
        k = 0
        while k < n:
            k = library.ik_table_run(handle, k, n, state.ctypes.data, rotations.ctypes.data, positions.ctypes.data,
                                     twists.ctypes.data, accelerations.ctypes.data, out.ctypes.data, h,
                                     ik.ik._tol2, ik.ik._accept2, lower.ctypes.data, upper.ctypes.data,
                                     SINGULARITY_TOLERANCE)
            if k >= n:
                break
            ik.set_state(state[:6], state[6:12], state[12:])  # the knot before: Python solves knot k
            q, qd, qdd = ik.solve(reference._placements[k], twists[k], accelerations[k], h)
            out[0, k], out[1, k], out[2, k] = q, qd, qdd
            state[:6], state[6:12], state[12:] = q, qd, qdd
            k += 1
        ik.set_state(state[:6], state[6:12], state[12:])
        return True
    finally:
        library.ik_table_free(handle)

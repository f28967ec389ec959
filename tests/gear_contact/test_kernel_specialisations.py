"""Each numba kernel compiles once per argument type, not once per literal or per writability.

numba compiles a kernel, with everything it calls linked into its machine code, once for every distinct
tuple of argument types. A constant passed from another kernel (``_traverse(0, ...)``) is a literal type of
its own, and a read-only array another type than a writable one, so either multiplies the first compile
after an install: the engine's traversal was compiled twice, the table's interpolation 22 times, and the
stage and table kernels once more for every map shared read-only by ``contact_map.load_map``.

Oracle: numba's own record of what it compiled (``dispatcher.signatures``). After a workload that reaches
every such path (the exact and the cached contact search, a map tabulated, a table model from a map built
here and from one loaded from its file, stepped in the gear stage), no kernel of the library holds two
signatures that differ only by literal values or writability. Checked over everything this test process
compiled, not only the workload. (Passing a literal again, e.g. ``_traverse(0, ...)``, or dropping the
read-only view of ``make_table_data``, fails it.) A literal also reaches a kernel on the way to its final type:
``i = 0; ...; i += 1`` types ``i`` as ``Literal[int](0)`` first, and numba compiles the callee for that before
``int64`` (``bvh._node_frame`` and ``coupling.correct_port`` were, found by this test on CI's cold cache). What a
process loads from numba's disk cache it does not compile, so the check sees most on a cold cache (CI's fresh
clone); on a warm one, what was not cached.
"""
from __future__ import annotations

import numba as nb
import numpy as np
from numba.core import types
from numba.core.registry import CPUDispatcher

from gearcontact_fmu import contact_map as cm
from gearcontact_fmu import coupling, manufacturing, stage
from gearcontact_fmu.contact import bvh, kernels
from gearcontact_fmu.mesh_models import MeshModel, table
from gearcontact_fmu.mesh_models.base import N_OUT
from gearcontact_fmu.mesh_models.pcm import build_pcm_pair
from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams

KERNEL_MODULES = (kernels, bvh, stage, table, cm, manufacturing, coupling)
RES = MeshResolution(profile=0.3e-3, face=3e-3)
GRID = MapGrid(points_per_pitch=4, s_points=6, max_torque=120.0)


def _plain(t):
    """The type with literal values and writability forgotten (hashable)."""
    t = types.unliteral(t)
    if isinstance(t, types.Array):
        return ("array", t.dtype, t.ndim, t.layout)
    if isinstance(t, types.BaseTuple):
        return (getattr(t, "instance_class", tuple), tuple(_plain(x) for x in t.types))
    return t


def _duplicates() -> list[str]:
    found = []
    for mod in KERNEL_MODULES:
        for name, obj in vars(mod).items():
            if not isinstance(obj, CPUDispatcher):
                continue
            seen = {}
            for sig in obj.signatures:
                key = tuple(_plain(a) for a in sig)
                if key in seen:
                    found.append(f"{mod.__name__}.{name}: {seen[key]} and {sig}")
                seen[key] = sig
    return found


def _step_table_model(cmap):
    model = MeshModel(eval=table.table_eval, data=table.make_table_data(cmap), fidelity="table", kind="mesh")
    st = stage.GearStage(model, ratio=4.0)
    w = 20.0
    st.initialize(0.0, 0.0, w, 0.0, w / 4.0)
    for k in range(3):
        st.step(k * 1e-4, 1e-4, w * (k + 1) * 1e-4, w, w / 4.0 * (k + 1) * 1e-4, w / 4.0)


def test_no_kernel_is_compiled_twice_for_one_argument_type(tmp_path):
    gear, pcm = BevelGearParams(), PCMParams()
    pair = build_pcm_pair(gear, pcm, RES)
    # the contact search, exact and cached (the cache's candidate collection is the traversal's second mode)
    for cached in (True, False):
        data = pair.data_with(friction=True, damping=True) if cached else pair.data
        out = np.zeros(N_OUT)
        for th in np.linspace(0.0, 0.05, 4):
            kernels.fixed_axis_eval(data, th, th / 4.0, 10.0, 2.5, out)
    built = cm.compute_map(pair, GRID)
    path = tmp_path / "map.npz"
    cm.save_map(built, path)
    loaded = cm.load_map(path, gear, pcm, GRID, n_rev=1)
    assert not loaded.values.flags.writeable and built.values.flags.writeable
    # the kernel data of a map built here and of one shared read-only: one numba type
    assert nb.typeof(table.make_table_data(built)) == nb.typeof(table.make_table_data(loaded))
    _step_table_model(built)
    _step_table_model(loaded)
    problems = _duplicates()
    assert not problems, "compiled twice for one argument type:\n" + "\n".join(problems)

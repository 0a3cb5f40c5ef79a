"""A control step's physics chunks in one compiled pass: MuJoCo's `mj_step` called from a kernel, with the ego's
contact check and the traffic's pose writes between chunks, as `Physics.advance` does them in Python.

Between two chunks `Physics.advance` calls the task's substep callback: sample the ego's contacts
(`CollisionSensor.sample`), then move the traffic one substep along its plan and write its mocap poses
(`Traffic.advance`). Most chunks need nothing else, and a kernel does exactly that much: it steps the physics,
reads the ego's contact-sensor counts, and copies the plan's next poses into `mocap_pos` / `mocap_quat`. It hands
the chunk back to the Python callback whenever more is due: a contact to identify, a traffic decision, a
chunk that is not one whole substep. The numbers are those of the Python loop, bit for bit (checked by
tests/test_chunks.py); only the interpreter between chunks is gone.

`mj_step` is MuJoCo's own C function (from the library the `mujoco` package ships), called through its address:
the same code as `mujoco.mj_step`, without the Python bindings' error interception, so a MuJoCo fatal error
inside a chunk (none occurs in mjdrive's worlds) ends the process with MuJoCo's message instead of raising.
"""

from __future__ import annotations

import ctypes
import glob
import os
from collections.abc import Callable
from typing import TYPE_CHECKING

import mujoco
import numpy as np

from mjdrive.compiled import INTERPRETED
from mjdrive.compiled import jit as _jit
from mjdrive.sensors import CollisionSensor

if TYPE_CHECKING:
    from mjdrive.tasks.base import Physics
    from mjdrive.traffic import Traffic

DONE, CALLBACK = 0, 1  # the kernel's status: every chunk stepped; the last chunk needs the Python callback

if not INTERPRETED:
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic

    @intrinsic
    def _call_mj_step(typingctx, fn, model, data):
        """Call `void mj_step(const mjModel*, mjData*)` at address `fn` (all three addresses as integers)."""
        def codegen(context, builder, signature, args):
            pointer = ir.IntType(8).as_pointer()
            function = ir.FunctionType(ir.VoidType(), [pointer, pointer]).as_pointer()
            builder.call(builder.inttoptr(args[0], function),
                         [builder.inttoptr(args[1], pointer), builder.inttoptr(args[2], pointer)])
            return context.get_dummy_value()
        return types.void(types.intp, types.intp, types.intp), codegen
else:  # the same call from Python
    _MJ_STEP = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)

    def _call_mj_step(fn, model, data):
        """Call `void mj_step(const mjModel*, mjData*)` at address `fn` (all three addresses as integers)."""
        _MJ_STEP(fn)(model, data)


def mj_step_address() -> int:
    """Address of MuJoCo's `mj_step` in the library the `mujoco` package loaded (0 if it cannot be found)."""
    folder = os.path.dirname(mujoco.__file__)
    names = glob.glob(os.path.join(folder, "libmujoco.so*")) + glob.glob(os.path.join(folder, "libmujoco*.dylib"))
    names += glob.glob(os.path.join(folder, "mujoco.dll"))
    for name in names:
        try:
            return int(ctypes.cast(ctypes.CDLL(name).mj_step, ctypes.c_void_p).value or 0)
        except (OSError, AttributeError):
            continue
    return 0


@_jit
def run_chunks(step_fn, model, data, nstep, chunk, dt, sensordata, contacts, ground_contacts, check_contacts,
               moving, plan_pos, plan_quat, k, n_plan, accumulated, substep, time, mocap_pos, mocap_quat, mocap_ids):
    """Step `nstep` physics steps in chunks of `chunk`; after each chunk, as `Physics.advance`'s callback would:
    check the ego's contacts (sensordata[contacts] > sensordata[ground_contacts]: touching something besides the
    ground) if `check_contacts`, and if `moving`, take the plan's next substep as `Traffic.advance` does (k of
    n_plan taken; `accumulated` [s] toward the next substep of `substep` [s]; the traffic's `time` [s]) and write
    its poses into the mocap rows `mocap_ids`. Returns (steps done, status, the last chunk's steps, k,
    accumulated, time): status CALLBACK when the last chunk stepped needs the Python callback instead (a contact,
    a decision due, or not exactly one substep), before any of its own work."""
    done = 0
    while done < nstep:
        n = min(chunk, nstep - done)
        for _ in range(n):
            _call_mj_step(step_fn, model, data)
        done += n
        if check_contacts and sensordata[contacts] > sensordata[ground_contacts]:
            return done, CALLBACK, n, k, accumulated, time
        if moving:
            total = accumulated + n * dt  # `Traffic.advance`, operation for operation
            substeps = int(total / substep + 1e-6)
            if substeps != 1 or k >= n_plan:
                return done, CALLBACK, n, k, accumulated, time
            accumulated = total - substeps * substep
            k += 1
            time += substeps * substep
            for i in range(len(mocap_ids)):
                row = mocap_ids[i]
                for j in range(3):
                    mocap_pos[row, j] = plan_pos[k - 1, i, j]
                for j in range(4):
                    mocap_quat[row, j] = plan_quat[k - 1, i, j]
    return done, DONE, 0, k, accumulated, time


_NO_PLAN = (np.zeros((0, 0, 3)), np.zeros((0, 0, 4)), 0, 0, 0.0, 1.0, 0.0)  # a `Traffic.pose_cursor` of no traffic
_NO_IDS = np.zeros(0, dtype=np.int64)


class ChunkRunner:
    """`Physics.advance` for a task whose substep callback samples the ego's contacts and then (with `traffic`)
    advances the traffic: the chunks in `run_chunks`, the callback only for the chunks that need it."""

    def __init__(self, collision_sensor: CollisionSensor, traffic: Traffic | None, step_fn: int):
        self.collision_sensor = collision_sensor
        self.contacts, self.ground_contacts = collision_sensor.contact_sensors
        self.traffic = traffic
        self.step_fn = step_fn

    @classmethod
    def of(cls, collision_sensor: CollisionSensor, traffic: Traffic | None) -> ChunkRunner | None:
        """A runner where it can work (numba installed and on, MuJoCo's `mj_step` found, the ego's contact
        sensors in the world), else None (`Physics.advance` then runs the chunks in Python)."""
        if collision_sensor.contact_sensors is None or traffic is not None and traffic.mocap_ids is None:
            return None
        step_fn = _step_address()
        return cls(collision_sensor, traffic, step_fn) if step_fn else None

    def __call__(self, physics: Physics, nstep: int, callback: Callable[[Physics, float], None]) -> None:
        """`nstep` physics steps with `callback(physics, dt)` for the chunks the kernel hands back."""
        model, data = physics.raw_model, physics.raw_data
        addresses = model._address, data._address
        chunk, dt = physics.substep_interval, physics.substep_dt
        sensordata, mocap_pos, mocap_quat = data.sensordata, data.mocap_pos, data.mocap_quat
        traffic, sensor = self.traffic, self.collision_sensor
        left = nstep
        while left > 0:
            cursor = traffic.pose_cursor() if traffic is not None else None
            if traffic is not None and cursor is None:  # no plan yet: the callback's first substep decides
                n = min(chunk, left)
                mujoco.mj_step(model, data, n)
                left -= n
                callback(physics, n * dt)
                continue
            plan_pos, plan_quat, k, n_plan, accumulated, substep, time = cursor or _NO_PLAN
            done, status, last, k, accumulated, time = run_chunks(
                self.step_fn, *addresses, left, chunk, dt, sensordata, self.contacts, self.ground_contacts,
                not sensor.pending, cursor is not None, plan_pos, plan_quat, k, n_plan, accumulated, substep, time,
                mocap_pos, mocap_quat, traffic.mocap_ids if cursor is not None else _NO_IDS)
            if cursor is not None:
                traffic.moved(k, accumulated, time)
            left -= done
            if status == CALLBACK:
                callback(physics, last * dt)


def _step_address() -> int:
    """`mj_step_address`, looked up once per process."""
    global _STEP
    if _STEP is None:
        _STEP = mj_step_address()
    return _STEP


_STEP: int | None = None

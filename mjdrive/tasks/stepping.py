"""The substep loop: a control step's physics in chunks, with the work due between chunks. It is the one loop of
every env: `Physics.advance` runs it for the dm-control env and the gymnasium env over it, and the batched env
for each of its copies.

A control step runs its physics steps in chunks of `Substeps.chunk` steps (a task's substep period, 0.02 s). After
each chunk comes the task's substep work: sample the ego's contacts (`CollisionSensor.sample`), then move the
traffic one substep along its plan of poses and write them into mocap (`Traffic.advance`). Most chunks need
nothing else, and `run_chunks` (a kernel: MuJoCo's `mj_step` called from compiled code) steps them and does that
much itself: it reads the ego's contact-sensor counts and copies the plan's next poses into `mocap_pos` /
`mocap_quat`. It hands a chunk back to Python whenever more is due (status CALLBACK: a contact to identify, a
traffic decision, a chunk that is not one whole substep; the task's callback then does the chunk's work) and,
where a task asks for one, at a fixed period of chunks (status TICK: `Substeps.tick`, e.g. a controller's
period within a longer env step).

`mj_step` is MuJoCo's own C function (from the library the `mujoco` package ships), called through its address:
the same code as `mujoco.mj_step`, without the Python bindings' error interception, so a MuJoCo fatal error
inside a chunk (none occurs in mjdrive's worlds) ends the process with MuJoCo's message instead of raising.
"""

from __future__ import annotations

import ctypes
import glob
import os
from collections.abc import Callable
from typing import Any, NamedTuple

import mujoco
import numpy as np

from mjdrive.compiled import INTERPRETED, jit
from mjdrive.sensors import CollisionSensor
from mjdrive.traffic import Traffic
from mjdrive.traffic.motion import substeps_due
from mjdrive.traffic.state import PlanCursor

DONE, CALLBACK, TICK = 0, 1, 2  # the kernel's status bits: every step done; the last chunk needs the callback, a tick

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
else:
    def _call_mj_step(fn, model, data):
        """The same call from Python (the interpreted debug mode)."""
        ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p)(fn)(model, data)


class Contacts(NamedTuple):
    """The ego's contact check between chunks: sensordata rows of the world's counts of the ego's contacts and of
    its contacts with the ground (touching something else iff the first exceeds the second; row -1: every chunk goes
    back to Python), and whether to check (not once a contact of this control step is known)."""

    sensordata: np.ndarray
    ego: int
    ground: int
    check: bool


class Mocap(NamedTuple):
    """Where the traffic's poses go: data.mocap_pos, data.mocap_quat and the traffic slots' rows in them."""

    pos: np.ndarray
    quat: np.ndarray
    rows: np.ndarray


NO_CURSOR = PlanCursor(np.zeros((0, 0, 3)), np.zeros((0, 0, 4)), 0, 0, 0.0, 1.0, 0.0, False)
NO_ROWS = np.zeros(0, dtype=np.int64)


@jit
def run_chunks(mj, nstep, chunk, dt, contacts, cursor, mocap, tick_every, ticked):
    """Step up to `nstep` physics steps in chunks of `chunk` (each dt [s]) with `mj_step` (mj: its address, the model's
    and the data's; address 0: the physics is stepped already, only the work between chunks is due); after each chunk
    check the ego's `contacts`, and if the cursor's traffic is moving, take its plan's next substep as `Traffic.advance`
    does and write its poses into `mocap`. Returns (steps done, status, the last chunk's steps, chunks since the last
    tick, the cursor's k, accumulated [s] and time [s]): status CALLBACK when the last chunk needs the Python callback
    (a contact, a decision due, not exactly one substep), before any of its own work; TICK (also) when `tick_every`
    chunks have passed since the last tick (`ticked` of them had, at the call) and steps are left."""
    k, accumulated, time = cursor.k, cursor.accumulated, cursor.time
    done = 0
    while done < nstep:
        n = min(chunk, nstep - done)
        if mj[0]:
            for _ in range(n):
                _call_mj_step(mj[0], mj[1], mj[2])
        done += n
        ticked += 1
        tick = DONE
        if tick_every > 0 and ticked >= tick_every and done < nstep:
            tick, ticked = TICK, 0
        touching = contacts.ego >= 0 and contacts.sensordata[contacts.ego] > contacts.sensordata[contacts.ground]
        if contacts.ego < 0 or contacts.check and touching:
            return done, CALLBACK | tick, n, ticked, k, accumulated, time
        if cursor.moving:
            substeps, rest = substeps_due(accumulated, n * dt, cursor.substep)
            if substeps != 1 or k >= cursor.n_plan:
                return done, CALLBACK | tick, n, ticked, k, accumulated, time
            accumulated = rest
            k += 1
            time += substeps * cursor.substep
            for i in range(len(mocap.rows)):
                row = mocap.rows[i]
                for j in range(3):
                    mocap.pos[row, j] = cursor.pos[k - 1, i, j]
                for j in range(4):
                    mocap.quat[row, j] = cursor.quat[k - 1, i, j]
        if tick:
            return done, tick, n, ticked, k, accumulated, time
    return done, DONE, 0, ticked, k, accumulated, time


class Substeps:
    """What runs between one world's physics chunks: `callback(physics, dt)` (the task's substep work, given the
    chunk's duration dt [s]) for the chunks that need Python, and what `run_chunks` does itself: the ego's contact
    check (`sensor`: its counts; without sensors every chunk goes to the callback) and the substeps of `traffic`.
    `tick(physics)`, if set (`set_tick`), runs every `tick_every` chunks within a control step (not after its last)."""

    def __init__(self, timestep: float, period: float, callback: Callable[[Any, float], None],
                 sensor: CollisionSensor | None = None, traffic: Traffic | None = None):
        """timestep: the physics step [s]; period: between callbacks [s] (the nearest whole number of steps, at least
        one)."""
        self.dt = float(timestep)  # [s]
        self.chunk = max(1, int(round(period / self.dt)))  # physics steps
        self.callback, self.sensor, self.traffic = callback, sensor, traffic
        self.tick: Callable[[Any], None] | None = None
        self.tick_every = 0  # chunks
        self._mj_step = mj_step_address()

    def set_tick(self, tick: Callable[[Any], None] | None, period: float = 0.0) -> None:
        """Run `tick(physics)` every `period` [s] of physics (a whole number of chunks, at least one) within each
        `advance` (not after its last chunk: the next control step begins there); None: no tick."""
        self.tick = tick
        self.tick_every = 0 if tick is None else max(1, int(round(period / (self.chunk * self.dt))))

    def advance(self, physics, nstep: int) -> None:
        """`nstep` physics steps of `physics` (its raw_model, raw_data) with the work between chunks (every chunk's in
        the callback where `physics.every_chunk`)."""
        self._run(physics, nstep, self._mj_step)

    def between_chunks(self, physics, n: int) -> None:
        """The work after a chunk of `n` steps that something else stepped (the batched env's rollout backend)."""
        self._run(physics, n, 0)

    def _run(self, physics, nstep: int, step_fn: int) -> None:
        data, traffic, sensor = physics.raw_data, self.traffic, self.sensor
        mj = (step_fn, physics.raw_model._address, data._address)
        rows = sensor.contact_sensors if sensor is not None and not physics.every_chunk else None
        ego, ground = rows if rows is not None else (-1, -1)
        mocap = Mocap(data.mocap_pos, data.mocap_quat, NO_ROWS if traffic is None else traffic.mocap_ids)
        left, ticked = nstep, 0
        while left > 0:
            cursor = NO_CURSOR if traffic is None else traffic.cursor()
            contacts = Contacts(data.sensordata, ego, ground, sensor is None or not sensor.pending)
            done, status, last, ticked, k, accumulated, time = run_chunks(
                mj, left, self.chunk, self.dt, contacts, cursor, mocap, self.tick_every, ticked)
            if cursor.moving:
                traffic.moved(k, accumulated, time)
            left -= done
            if status & CALLBACK:
                self.callback(physics, last * self.dt)
            if status & TICK:
                self.tick(physics)


def mj_step_address() -> int:
    """Address of MuJoCo's `mj_step` in the library the `mujoco` package loaded (looked up once per process)."""
    global _STEP
    if _STEP is None:
        folder = os.path.dirname(mujoco.__file__)
        names = glob.glob(os.path.join(folder, "libmujoco.so*")) + glob.glob(os.path.join(folder, "libmujoco*.dylib"))
        names += glob.glob(os.path.join(folder, "mujoco.dll"))
        for name in names:
            try:
                _STEP = int(ctypes.cast(ctypes.CDLL(name).mj_step, ctypes.c_void_p).value or 0)
            except (OSError, AttributeError):
                continue
            if _STEP:
                break
        else:
            raise RuntimeError(f"MuJoCo's library (libmujoco) was not found in {folder}")
    return _STEP


_STEP: int | None = None

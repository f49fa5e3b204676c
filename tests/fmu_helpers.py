"""Drive an FMU straight through FMPy for the plant tests (independent of cosim's adapter),
and an independent rigid-body model of the same chain in Pinocchio."""

from __future__ import annotations

import ctypes

import numpy as np
import pinocchio as pin
from fmpy import read_model_description

from cosim.plant.lifecycle import open_instance


class FmuInstance:
    """One instantiated FMU (CS or ME, FMI 2 or 3) with its log messages kept in ``messages``.
    Instantiation and freeing go through cosim's FMI life cycle; every other call is FMPy's
    own, so the plant tests see FMPy's exceptions."""

    def __init__(self, path, kind: str = "CoSimulation", parameters: dict | None = None,
                 initialize: bool = True):
        self.md = read_model_description(path)
        self.fmi_version = int(self.md.fmiVersion[0])
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.kind = kind
        self._instance = open_instance(path, self.md, kind, "arm")
        self.fmu = self._instance.fmu
        self.messages = self._instance.messages
        if self.fmi_version == 2:
            self.fmu.setupExperiment(startTime=0.0)
        self.n = sum(1 for v in self.md.modelVariables if v.name.startswith("q["))
        self.nx = len(self.md.derivatives)  # continuous states (2n rigid, 4n elastic)
        if initialize:
            self.fmu.enterInitializationMode()
            if parameters:
                self.set(parameters)
            self.fmu.exitInitializationMode()
            if kind == "ModelExchange":
                self._enter_continuous_time()

    def _enter_continuous_time(self):
        if self.fmi_version == 2:
            self.fmu.enterEventMode()
            self.fmu.newDiscreteStates()
        self.fmu.enterContinuousTimeMode()

    def refs(self, names):
        return [self.vr[n] for n in names]

    def set(self, values: dict):
        refs = self.refs(values)
        vals = [float(v) for v in values.values()]
        if self.fmi_version == 2:
            self.fmu.setReal(refs, vals)
        else:
            self.fmu.setFloat64(refs, vals)

    def get(self, names) -> np.ndarray:
        refs = self.refs(names)
        if self.fmi_version == 2:
            return np.array(self.fmu.getReal(refs))
        return np.array(self.fmu.getFloat64(refs))

    def names(self, base: str) -> list[str]:
        if base == "M":
            return [f"M[{i + 1},{j + 1}]" for i in range(self.n) for j in range(self.n)]
        return [f"{base}[{i + 1}]" for i in range(self.n)]

    def state(self) -> np.ndarray:
        return self.get(self.names("q") + self.names("qdot"))

    def do_step(self, t: float, h: float):
        self.fmu.doStep(t, h)

    # Model Exchange
    def set_states(self, x):
        x = np.ascontiguousarray(x, dtype=float)
        ptr = x.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self.fmu.setContinuousStates(ptr, self.nx)

    def derivatives(self) -> np.ndarray:
        dx = np.zeros(self.nx)
        ptr = dx.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        if self.fmi_version == 2:
            self.fmu.getDerivatives(ptr, self.nx)
        else:
            self.fmu.getContinuousStateDerivatives(ptr, self.nx)
        return dx

    def directional_derivative(self, unknowns, knowns, seed) -> np.ndarray:
        return np.array(self.fmu.getDirectionalDerivative(self.refs(unknowns), self.refs(knowns),
                                                          list(seed)))

    def free(self):
        self._instance.close()


def pinocchio_chain(m, length, lc, inertia, g) -> pin.Model:
    """The planar chain as a Pinocchio model: RZ joints, links along x, gravity along -y."""
    model = pin.Model()
    parent = 0
    placement = pin.SE3.Identity()
    for i in range(len(m)):
        joint = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{i + 1}")
        body = pin.Inertia(m[i], np.array([lc[i], 0.0, 0.0]), np.eye(3) * inertia[i])
        model.appendBodyToJoint(joint, body, pin.SE3.Identity())
        parent = joint
        placement = pin.SE3(np.eye(3), np.array([length[i], 0.0, 0.0]))
    model.gravity.linear = np.array([0.0, -g, 0.0])
    return model


def pinocchio_terms(model: pin.Model, q, v):
    """M(q), C(q, v) v and G(q) from Pinocchio's CRBA and RNEA."""
    data = model.createData()
    M = pin.crba(model, data, np.asarray(q, float))
    M = np.triu(M) + np.triu(M, 1).T
    G = pin.computeGeneralizedGravity(model, data, np.asarray(q, float)).copy()
    nle = pin.nonLinearEffects(model, data, np.asarray(q, float), np.asarray(v, float)).copy()
    return M, nle - G, G


def chain_parameters(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A chain with non-trivial centre-of-mass offsets and inertias."""
    return {
        "m": rng.uniform(0.5, 3.0, n), "l": rng.uniform(0.4, 1.5, n),
        "lc": rng.uniform(0.1, 0.9, n), "I": rng.uniform(0.01, 0.5, n),
    }


def fmu_parameters(params: dict[str, np.ndarray], **extra) -> dict[str, float]:
    """Pipeline-style dict of arrays -> FMU scalar names."""
    out = {}
    for key, values in {**params, **extra}.items():
        values = np.atleast_1d(values)
        if key in ("g", "fc_vel", "rk4_step"):
            out[key] = float(values[0])
        else:
            out.update({f"{key}[{i + 1}]": float(x) for i, x in enumerate(values)})
    return out

"""The paper's two-link arm as a PythonFMU (FMI 2.0 Co-Simulation) under other names.

A plant from a different exporter for the plant-swapping tests: the same equations as the
built-in FMU (Lewis's arm, in closed form rather than by CRBA/RNEA), integrated by
the same fixed-step RK4 (sub-steps of at most ``rk4_step``), but with its own variable
names and no inertia-matrix outputs. ``fail_at`` makes doStep return an error from that
time on (seconds), ``crash_at`` kill the process that runs it (SIGSEGV, as a broken
binary would), and ``hang_at`` never return from doStep, deaf to SIGINT and SIGTERM (as a
binary blocked in a system call would be), for the error tests. SI units, radians.
"""

import os
import signal
import time
from math import ceil, cos, sin

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

INPUTS = ("shoulder_torque", "elbow_torque")
OUTPUTS = ("shoulder", "elbow", "shoulder_rate", "elbow_rate")
PARAMETERS = {"upper_mass": 0.8, "fore_mass": 2.3, "upper_length": 1.0, "fore_length": 1.0,
              "gravity": 9.8, "disturbance": 0.01, "shoulder_start": 0.1,
              "elbow_start": 0.1, "shoulder_rate_start": 10.0, "elbow_rate_start": 10.0,
              "rk4_step": 1e-4, "fail_at": 1e300, "crash_at": 1e300, "hang_at": 1e300}


class PythonArm(Fmi2Slave):
    author = "cosim tests"
    description = "Lewis's two-link arm, closed form, PythonFMU"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name in INPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous))
        for name, value in PARAMETERS.items():
            setattr(self, name, value)
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed))
        for name in OUTPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous))

    def exit_initialization_mode(self):
        self.shoulder, self.elbow = self.shoulder_start, self.elbow_start
        self.shoulder_rate, self.elbow_rate = self.shoulder_rate_start, self.elbow_rate_start

    def _derivative(self, x, tau):
        q1, q2, v1, v2 = x
        m1, m2, a1, a2, g = (self.upper_mass, self.fore_mass, self.upper_length,
                             self.fore_length, self.gravity)
        c2, s2 = cos(q2), sin(q2)
        m11 = (m1 + m2) * a1 * a1 + m2 * a2 * a2 + 2 * m2 * a1 * a2 * c2
        m12 = m2 * a2 * a2 + m2 * a1 * a2 * c2
        m22 = m2 * a2 * a2
        h1 = -m2 * a1 * a2 * (2 * v1 * v2 + v2 * v2) * s2
        h2 = m2 * a1 * a2 * v1 * v1 * s2
        g1 = (m1 + m2) * g * a1 * cos(q1) + m2 * g * a2 * cos(q1 + q2)
        g2 = m2 * g * a2 * cos(q1 + q2)
        b1 = tau[0] - h1 - g1 - self.disturbance
        b2 = tau[1] - h2 - g2 - self.disturbance
        det = m11 * m22 - m12 * m12
        return (v1, v2, (m22 * b1 - m12 * b2) / det, (m11 * b2 - m12 * b1) / det)

    def do_step(self, current_time, step_size):
        if current_time + step_size > self.crash_at:
            os.kill(os.getpid(), signal.SIGSEGV)
        if current_time + step_size > self.hang_at:
            # Python's handlers run only in this (the main) thread, between bytecodes: with
            # the signals blocked here and the thread asleep, none runs, as in C code.
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
            if os.environ.get("PYTHON_ARM_HANG_MARKER"):  # tells a test it is stuck now
                open(os.environ["PYTHON_ARM_HANG_MARKER"], "w").close()
            while True:
                time.sleep(3600)
        if current_time + step_size > self.fail_at:
            self.log(f"the arm refuses to step past fail_at = {self.fail_at} s")
            return False
        tau = (self.shoulder_torque, self.elbow_torque)
        n_sub = max(1, ceil(step_size / self.rk4_step - 1e-9))
        dt = step_size / n_sub
        x = (self.shoulder, self.elbow, self.shoulder_rate, self.elbow_rate)
        for _ in range(n_sub):
            k1 = self._derivative(x, tau)
            k2 = self._derivative([a + 0.5 * dt * b for a, b in zip(x, k1, strict=True)], tau)
            k3 = self._derivative([a + 0.5 * dt * b for a, b in zip(x, k2, strict=True)], tau)
            k4 = self._derivative([a + dt * b for a, b in zip(x, k3, strict=True)], tau)
            x = tuple(a + dt / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
                      for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4, strict=True))
        self.shoulder, self.elbow, self.shoulder_rate, self.elbow_rate = x
        return True

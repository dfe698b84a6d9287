"""The filter's state vector, laid out from the configured sensors' error models.

x = [s, v, a, k_1 .., k0_1 .., b_1 .., e_1 .., c_1 ..]: chainage of the train front [m], speed
[m/s], acceleration [m/s^2], then the error states the sensors declare:
  k   relative scale error of a speed/distance sensor (``scale_sigma`` > 0): the sensor
      measures (1 + k) times the true quantity; Gauss-Markov with ``scale_tau`` or a
      constant (random walk of ``scale_psd``) from its prior;
  k0  a constant scale error added to a Gauss-Markov one (``scale_offset_sigma`` > 0);
  b   speed bias [m/s] along the direction of motion (``bias_sigma`` > 0);
  c   an accelerometer's bias [m/s^2] (``bias_sigma`` > 0 of a sensor that measures
      acceleration), Gauss-Markov with ``bias_tau``;
  e   position-fix bias [m] of a position sensor (``fix_bias_sigma`` > 0), Gauss-Markov
      in the distance run (``fix_bias_length``) and in time (``fix_bias_tau``), or
      redrawn per reference (``fix_bias_per_reference``).
"""
from __future__ import annotations

import math

import numpy as np

from ..sensors import faults

KINEMATIC = 3   # s, v, a


class StateLayout:
    """Indices of the error states by sensor class, and their priors."""

    def __init__(self, models: dict, scale_psd: float, bias_psd: float):
        self.models = models
        n = KINEMATIC

        def block(names):
            nonlocal n
            idx = {name: n + i for i, name in enumerate(names)}
            n += len(idx)
            return idx
        relative = [s for s, m in models.items() if m.relative]
        self.scale = block([s for s in relative if models[s].scale_sigma > 0.0])
        self.offset = block([s for s in self.scale if models[s].scale_offset_sigma > 0.0])
        self.bias = block([s for s in relative if models[s].bias_sigma > 0.0])
        self.fix = block([s for s, m in models.items() if m.measures == "position" and m.fix_bias_sigma > 0.0])
        self.accel_bias = block([s for s, m in models.items() if m.measures == "acceleration" and m.bias_sigma > 0.0])
        self.n = n
        self.relative = frozenset(relative)
        self.accelerometers = frozenset(s for s, m in models.items() if m.measures == "acceleration")
        self.slip_sensors = frozenset(s for s in relative if faults.ADHESION & set(models[s].faults))
        # relative sensors whose disagreement with the others is checked as a fault episode
        self.episode_sensors = frozenset(s for s in relative
                                         if faults.SPEED & set(models[s].faults))
        self.per_reference = frozenset(s for s in self.fix if models[s].fix_bias_per_reference)
        # scale states: Gauss-Markov (index, tau, sigma); constants: random walks (index, psd)
        self.gauss_markov = [(i, models[s].scale_tau, models[s].scale_sigma) for s, i in self.scale.items()
                             if math.isfinite(models[s].scale_tau)]
        self.random_walk = [(i, scale_psd) for s, i in self.scale.items() if not math.isfinite(models[s].scale_tau)]
        self.random_walk += [(i, scale_psd) for i in self.offset.values()]
        self.random_walk += [(i, bias_psd) for i in self.bias.values()]
        for s, i in self.accel_bias.items():
            if math.isfinite(models[s].bias_tau):
                self.gauss_markov.append((i, models[s].bias_tau, models[s].bias_sigma))
        fixgm = [(i, models[s].fix_bias_length, models[s].fix_bias_tau, models[s].fix_bias_sigma)
                 for s, i in self.fix.items()]
        self.fix_decay = [g for g in fixgm if math.isfinite(g[1]) or math.isfinite(g[2])]   # others: constant
        # prior 1-sigma of every error state, and the relative sensors' ones (re-learnt together)
        sigma = np.zeros(n)
        for s, i in self.scale.items():
            sigma[i] = models[s].scale_sigma
        for s, i in self.offset.items():
            sigma[i] = models[s].scale_offset_sigma
        for s, i in self.bias.items():
            sigma[i] = models[s].bias_sigma
        for s, i in self.fix.items():
            sigma[i] = models[s].fix_bias_sigma
        for s, i in self.accel_bias.items():
            sigma[i] = models[s].bias_sigma
        self.prior_sigma = sigma
        self.relative_states = np.array(sorted([*self.scale.values(), *self.offset.values(), *self.bias.values()]),
                                        dtype=np.intp)
        self.scale_terms = [(name, i, self.offset.get(name)) for name, i in self.scale.items()]
        # the state a sensor's scale fault (a constant) is learnt in: its constant scale, else its scale
        self.fault_scale = {name: self.offset.get(name, i) for name, i in self.scale.items()}
        self.owner = {i: name for table in (self.scale, self.offset, self.bias, self.fix, self.accel_bias)
                      for name, i in table.items()}
        # a relative sensor's own error states (scale, offset, bias): indices
        owned: dict[str, list] = {}
        for table in (self.scale, self.offset, self.bias):
            for name, i in table.items():
                owned.setdefault(name, []).append(i)
        self.own_states = {name: np.array(sorted(idx), dtype=np.intp) for name, idx in owned.items()}

    def prior_covariance(self, speed_sigma: float, accel_sigma: float) -> np.ndarray:
        P = np.diag(self.prior_sigma ** 2)
        P[0, 0] = 1.0   # relative position until the first fix
        P[1, 1] = speed_sigma ** 2
        P[2, 2] = accel_sigma ** 2
        return P

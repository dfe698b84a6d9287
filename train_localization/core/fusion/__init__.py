"""Along-track fusion, split by concept (one line per module of this package):

  config.py        global tuning (FusionConfig) and the configured sensors' error models
  layout.py        the state vector laid out from those models
  models.py        process and measurement models (scalar measurements)
  limits.py        the derived thresholds and fault bounds (gates, z, ...), the policies switched off
  filter.py        the extended Kalman filter (filterpy) that runs the policies below
  pipeline.py      one reading through the policies: the ordered stages, their verdicts, the routing of effects
  events.py        the effects one policy asks of another, routed by the pipeline
  views.py         the hypotheses kept beside the filter as pure functions (motion views, excluded views, windows)
  component.py     the base of the filter's policy components
  bookkeeping.py   the filter's records that roll back with x and P (copy-on-write); each field has one writer
  counts.py        the counters: integrity events, readings accepted and gated, when each sensor was last accepted
  bank.py          the fault hypotheses' bank (impact.py) kept with the state, following every change of x
  history.py       late and out-of-order data: exact rollback and lazy re-application
  admission.py     every check that protects the filter from its inputs (one place, every path)
  shedding.py      load shedding at the inputs (a token bucket per topic)
  episodes.py      fault episodes of the relative sensors (slip, slide, radar scale faults)
  arbitration.py   disagreeing speed sources: the excluded sensor's view, suspension, the fix that decides
  motion_views.py  the motion model's own hypotheses (coasting, blind)
  plausibility.py  plausibility of the error states: an absorbed fault, the re-learn from the priors
  fixes.py         policies on absolute fixes (initialisation, consistency, unexplained, recalibration, revisits)
  lone.py          the solution without the relative sensor that carries the speed alone
  inertial.py      the accelerometer's own dead reckoning (position, speed, bias), which narrows it
  separation.py    solution separation over the relative sensors: protection for undetected faults
  solutions.py     the relative sensors' own solutions kept beside the filter, and fixes under each hypothesis
  impact.py        fault impact by construction (scale fault, unseen wheel slip, offset of a run of fixes)
  interval.py      the published interval, widened to cover every pending hypothesis, and the mode
  mode.py          the published mode (TrainState.mode); its meaning is in interval.py
  runner.py        the fixed-rate output grid the node and the offline runs share
"""
from .config import FusionConfig, default_models, fusion_config, sensor_models
from .filter import MODE_DEGRADED, MODE_INITIALISING, MODE_LOST, MODE_NOMINAL, Estimate, Mode, TrainFilter
from .history import order_key
from .runner import FusionRunner, estimate_to_msg

__all__ = ["FusionConfig", "default_models", "fusion_config", "sensor_models", "Estimate", "Mode", "TrainFilter", "order_key",
           "FusionRunner", "estimate_to_msg", "MODE_INITIALISING", "MODE_NOMINAL", "MODE_DEGRADED",
           "MODE_LOST"]

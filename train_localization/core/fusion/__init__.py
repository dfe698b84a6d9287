"""Along-track fusion, split by concept:

  config.py   global tuning (FusionConfig) and the configured sensors' error models
  layout.py   the state vector laid out from those models
  models.py   process and measurement models
  history.py  late and out-of-order data (exact rollback)
  filter.py   the filter and its fault policy (gating, slip, plausibility, consistency,
              unexplained fixes), modes and the published interval
  admission.py every check that protects the filter from its inputs (one place, every path)
  runner.py   the fixed-rate output grid the node and the offline runs share
"""
from .config import FusionConfig, default_models, fusion_config, sensor_models
from .filter import MODE_DEGRADED, MODE_INITIALISING, MODE_LOST, MODE_NOMINAL, Estimate, Mode, TrainFilter
from .history import order_key
from .runner import FusionRunner, estimate_to_msg

__all__ = ["FusionConfig", "default_models", "fusion_config", "sensor_models", "Estimate", "Mode", "TrainFilter", "order_key",
           "FusionRunner", "estimate_to_msg", "MODE_INITIALISING", "MODE_NOMINAL", "MODE_DEGRADED",
           "MODE_LOST"]

"""The safety chain behind the fusion (docs/reliability.md): what every consumer of the fused
state, an ETCS report, an event, an end of authority, switch positions or track hypotheses
admits, and how it tells a stream that has gone stale.

  admission.py     StreamAdmission: EN 50159's threats as checks on one input stream (stamps
                   against the consumer's clock and the stream's last, non-finite values, sizes),
                   the time-out after which a stream is stale
  plausibility.py  MotionGate: a state (or report) whose interval or speed the last admitted one
                   rules out over the elapsed time is refused
  state_stream.py  StateStream: the two in order for a stream of states
  fused_state.py   FusedStateStream: a train's TrainState stream as the wayside consumers admit
                   it (on a network, a new section placed on the last one's axis)
"""

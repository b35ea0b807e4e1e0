"""The alarm layer: score streams in, alarm start / end events out, at a false-alarm budget.

:mod:`~chatterspec.detection.alarms.rules`
    The rules (frame, persistence, CUSUM), their table :data:`~chatterspec.detection.alarms.rules.RULES`
    and labels; no numpy, so that the CLI parser can name the rules.
:mod:`~chatterspec.detection.alarms.steps`
    Each rule's state machine: its compiled step over a channel and the numpy form of the same step.
:mod:`~chatterspec.detection.alarms.streams`
    :class:`~chatterspec.detection.alarms.streams.AlarmStream` and
    :func:`~chatterspec.detection.alarms.streams.run_rule`: rules run over score streams (any
    chunking, the same alarms), start counts.
:mod:`~chatterspec.detection.alarms.calibration`
    Rule thresholds for a budget in false alarms per hour and the monitor's detector settings
    (:class:`~chatterspec.detection.alarms.calibration.MonitorSettings`).
"""

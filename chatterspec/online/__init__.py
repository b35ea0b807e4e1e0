"""The online monitor: the numeric side of live detection.

:mod:`~chatterspec.online.monitor` (``ChatteringMonitor``: both SVSFs and the STFT frames, verdicts
and alarm rule, pushed sample block by sample block, with the same numbers as the batch path whatever
the chunking; its settings and output types), its compiled push kernels, the reading of measurement
streams and their checks (:mod:`~chatterspec.online.stream`; simulated streams in
:mod:`~chatterspec.online.simulated_stream`), identification beside the monitor
(:mod:`~chatterspec.online.identification_monitor`), the fault state per channel
(:mod:`~chatterspec.online.fault_state`), thresholds from a recorded healthy run
(:mod:`~chatterspec.online.recorded_calibration`) and the realistic bench
(:mod:`~chatterspec.online.realistic_bench`).

Nothing here imports ``rerun``: the recordings and the live viewer are the layer above,
:mod:`chatterspec.viewer`.
"""

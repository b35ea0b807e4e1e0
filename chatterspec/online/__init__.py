"""The online monitor: the numeric side of live detection.

:mod:`~chatterspec.online.monitor` (``ChatteringMonitor``: both SVSFs, in
:mod:`~chatterspec.online.monitor_filters`, and the STFT frames, verdicts and alarm rule, in
:mod:`~chatterspec.online.monitor_frames`, pushed sample block by sample block, with the same numbers
as the batch path whatever the chunking), its compiled push kernels, its types
(:mod:`~chatterspec.online.monitor_types`), and the reading of measurement streams
(:mod:`~chatterspec.online.stream`, :mod:`~chatterspec.online.stream_checks`, simulated streams in
:mod:`~chatterspec.online.simulated_stream`).

Nothing here imports ``rerun``: the recordings and the live viewer are the layer above,
:mod:`chatterspec.viewer`.
"""

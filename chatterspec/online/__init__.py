"""Online monitor and Rerun output.

Rerun output of the online monitor: sinks (file / live viewer), entity layout, default blueprint.

``rerun`` is imported lazily inside the functions: ``import chatterspec.online``
does not load it, and the numeric core never imports this module.

Entity layout (timeline ``time``: integer nanoseconds, every time rounded once by
:func:`chatterspec.online.rerun_log.to_ns`; ``<c>`` is an output channel name, ``<k>`` its
1-based index). Per-sample and per-frame series hold ONE row per sample / frame for all
``m`` channels (series ``j`` = channel ``j``, named and coloured in the static
``SeriesLines`` / ``SeriesPoints``): Rerun's cost is per row (a 16-byte row id and an
8-byte time besides the values), so this halves the recording time of the per-channel
layout. Each channel's view shows only its own series (blueprint overrides of
``visible_series``; hidden series do not enter the auto-scaled y range):

========================================  =============================================================
``/chattering/e``                         everything per sample, one row per sample: the chattering
                                          ``e(k|k-1)`` of the auxiliary filter per channel (series
                                          ``0 .. m-1``), then for raw data per channel the measurement
                                          [and the ``sat``-SVSF estimate ``C x(k|k)``] (series
                                          ``m + c k + j``, k = 1 or 2): m, 2 m or 3 m per row
``/chattering/psi``                       the SVSF boundary layer ``+psi_0, -psi_0, +psi_1, ...`` (when
                                          known): 2 m per row, at each batch's first and last sample
``/spectrum/<c>``                         one STFT column per hop (``Tensor``, dim ``freq``, float32;
                                          float64 with ``RerunLogger(spectrum_dtype="float64")``)
``/spectrogram/<c>``                      ``10 log10(S / threshold)`` dB over the band, clipped
``/detection/statistic_db``               ``10 log10`` of the largest ``S / threshold`` over the tested
                                          bins: m per row, one row per frame
``/detection/threshold_db``               the decision level, 0 dB (one series)
``/detection/fault/<c>``                  the statistic at flagged frames only (red points)
``/detection/verdict``                    per-frame verdict, 1 = fault, 0 = healthy (m, not drawn), then
                                          the alarm rule's statistic (m), the frame score ``-log p`` (m)
                                          and the rule's threshold (1): 3 m + 1 per row
``/frequency/peak_hz``                    tested bin with the largest excess power ``S - E`` (Hz): m per row
``/frequency/most_significant_hz``        tested bin with the largest ``S / threshold`` (Hz): m per row
``/threshold/<c>``, ``/expected/<c>``     static frame threshold and expected healthy spectrum per bin
``/state/0_truth``                        true fault timeline (simulated data only), the top lane
``/state/<k>_<c>``                        verdict lane ``healthy`` / ``fault``, in channel order
``/events``                               text log of fault start / end events
========================================  =============================================================

The paths are constants of :mod:`chatterspec.online.blueprint` (``CHATTERING``, ``PSI``,
``STATISTIC``, ``THRESHOLD``, ``VERDICT``, ``PEAK_HZ``, ``MOST_SIGNIFICANT_HZ``,
:func:`~chatterspec.online.blueprint.fault_entity`, :func:`~chatterspec.online.blueprint.lane_entity`).

Everything time-indexed is sent column-wise (``send_columns``) from zero-copy arrow
views, also the spectra: one ``Tensor`` row per frame, built in bulk from numpy
(``rr.Tensor`` has no batch constructor), so a reader sees the same rows as from one
``rr.log`` per frame. A live viewer gets every update at once; a file gets the per-sample
series in batches of 20 s of 1 kHz data and the frames in batches of a minute at a 0.2 s hop
(and the rest on close).

The spectrogram band defaults to the detector's tested bins capped at 3x the model's
highest natural frequency (EHA: 1-150 Hz). In a file it is ONE float16 tensor per
channel for the whole record (one column per frame, no padding; blocks of at most an
hour on longer streams), logged at the record's start, and the file's blueprint shows
exactly the spectrogram's time span in every time-series view and opens paused on the
whole record. A live viewer gets a scrolling view of the last ``scroll_frames``
columns after every frame, whose time dimension names the newest column's time.

Default recording folder of ``chatterspec demo``: ``recordings/`` in the
current directory (git-ignored).
"""

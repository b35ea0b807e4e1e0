"""Online monitor and Rerun output.

Rerun output of the online monitor: sinks (file / live viewer), entity layout, default blueprint.

``rerun`` is imported lazily inside the functions: ``import chatterspec.online``
does not load it, and the numeric core never imports this module.

Entity layout (timeline ``time``, seconds; ``<c>`` is an output channel name):

====================================  =================================================================
``/chattering/<c>/e``                 chattering ``e(k|k-1)`` of the auxiliary filter (bulk ``send_columns``)
``/chattering/<c>/psi_upper|lower``   the SVSF boundary layer ``+-psi`` (when known)
``/signal/<c>/measured|estimate``     measurement and ``sat``-SVSF estimate ``C x(k|k)`` (raw data only)
``/spectrum/<c>``                     one exact STFT column per hop (``Tensor``, dim ``freq``, float64)
``/spectrogram/<c>``                  scrolling 2-D view, dB re the expected healthy frame spectrum
``/detection/<c>/peak_ratio``         largest ``S / threshold`` over the tested bins, per frame
``/detection/<c>/threshold``          the decision level 1.0 on the same axis
``/detection/<c>/verdict``            per-frame verdict, 1 = fault, 0 = healthy
``/threshold/<c>``, ``/expected/<c>`` static frame threshold and expected healthy spectrum per bin
``/state/<c>``                        state lane ``healthy`` / ``fault``
``/truth/plant``                      true fault timeline (simulated data only)
``/events``                           text log of fault start / end events
====================================  =================================================================

Everything time-indexed is sent column-wise (``send_columns``), also the exact
spectra: one ``Tensor`` row per frame, built in bulk from numpy (``rr.Tensor`` has
no batch constructor), so a reader sees the same rows as from one ``rr.log`` per
frame. A live viewer gets every update at once; a file gets batches of ~10 s of
data (and the rest on close), which keeps logging well below the analysis cost.

The scrolling spectrogram is a 2-D float16 ``Tensor`` (dB, ``freq`` x ``time``) of the
last ``scroll_frames`` columns; it goes to a live viewer at every hop, into a file
only every ``file_scroll_every`` hops (default: one block per ``scroll_frames``, so
the blocks tile the record) and at the end (a 2-D tensor per hop would cost ~90 MB
per minute).

Default recording folder of ``chatterspec demo``: ``recordings/`` in the
current directory (git-ignored).
"""

"""Chattering to verdicts: chattering records, periodograms and STFT, thresholds, detection."""

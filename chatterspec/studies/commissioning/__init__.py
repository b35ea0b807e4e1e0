"""Commissioning: from a plant's own healthy recording to a fitted, checked model (goes beyond the papers).

Every result of the papers is measured on plants that match their nominal model exactly; a real
actuator never does (bulk modulus moves with temperature and entrained air, friction with oil
temperature, the sensor noise is what the sensors give), and the chattering detects *any* mismatch.
:func:`commission` builds the nominal model, its noise and its boundary layer from a healthy recording
and says whether that model is good enough:

1. **Split** (``holdout``, default the last third): fit on the first part, check on the rest.
2. **Parameters** (:mod:`.fits`): every physical parameter the model declares, fitted at once
   by fault identification's instrumental-variables regression of the chattering (eq 23) with one
   hypothesis holding them all; the plant's value with a delta-method interval. Identifiability is
   checked first on the fit's information matrix: a combination the data see only to more than 10 %
   is refused, naming the parameters and the excitation (or the length) that would identify them.
3. **Noise** (:mod:`.fits`): diag(Q) and diag(R) from the chattering's lag-0 and lag-1
   autocovariances under its MA(1) law (eq 23, 56), by weighted non-negative least squares with
   intervals from the autocovariances' own variance; entries the data cannot see are bounded, not
   fitted; the parameters are identified once more when the fitted noise moved their weights.
4. **psi**: 3 standard deviations of the fitted model's chattering per output (eq 58), as the catalogue.
5. **Check** (:mod:`.adequacy`): on the held-out part, whiteness of each channel's chattering
   (Ljung-Box on its MA(1) innovations), its averaged spectrum against the exact threshold, and the
   monitor's alarm starts at its default budget; "adequate" or, where not, which channel and band.
6. **File** (:mod:`.result`): :meth:`Commissioning.write` writes the fitted model file with a
   ``[commissioning]`` table (data file and SHA-256, spans, every estimate with its interval and the
   nominal it replaced, Q and R with intervals, the check, the chatterspec version), atomically.

``docs/commissioning.md`` derives every step and says where it goes beyond the papers.

Examples
--------
>>> import chatterspec as cs
>>> res = cs.commission("nominal.toml", z, u)        # doctest: +SKIP
>>> print(res.table()); res.write("fitted.toml")     # doctest: +SKIP
"""

from .adequacy import AdequacyCheck, ChannelCheck, check_model
from .fits import FittedParameter, NoiseFit, ParameterFit, fit_noise, fit_parameters
from .procedure import chattering, commission, nominal_spec
from .result import Commissioning, DataSource, read_recording

__all__ = [
    "AdequacyCheck",
    "ChannelCheck",
    "Commissioning",
    "DataSource",
    "FittedParameter",
    "NoiseFit",
    "ParameterFit",
    "chattering",
    "check_model",
    "commission",
    "fit_noise",
    "fit_parameters",
    "nominal_spec",
    "read_recording",
]

"""Model-test discrepancy workflow: find where a model and measured FRFs disagree, name the
missing effect from a library, add it to the model and show the gap shrink.

The method is described in ``docs/discrepancy.md``; the command ``ssidlab discrepancy`` and
its JSON keys in ``../shared/contract.md``. Modules:

- ``effects``: the library (the contract's effect names) and how each changes M, C, K;
- ``weights``: noise weights from ``H_var``, coherence or roughness;
- ``response``: the nominal receptance at the lines, and fitted modal damping;
- ``localise``: the residual compressed per candidate location, and its localisation;
- ``fit``: the parameters of every effect at every location;
- ``search``: one round of fitting and EBIC ranking; ``search_json`` its JSON;
- ``stand_noise``: on a test stand, the reactions' noise modelled exactly (errors in variables);
- ``workflow``: :func:`find_discrepancy`;
- ``report``: gaps by band and FRF, paired modes, :class:`DiscrepancyResult`;
- ``plots``: PNG figures; ``cases``: seeded test cases with hidden effects.
"""

from .effects import (
    EFFECT_NAMES,
    PARAMETER_KEYS,
    Effect,
    apply_effect,
    apply_effect_to_model,
)
from .report import GAP_METRIC, DiscrepancyResult
from .workflow import check_model, find_discrepancy

__all__ = [
    "EFFECT_NAMES",
    "GAP_METRIC",
    "PARAMETER_KEYS",
    "DiscrepancyResult",
    "Effect",
    "apply_effect",
    "apply_effect_to_model",
    "check_model",
    "find_discrepancy",
]

"""The diagnosis chain's results as typed objects (python-control's ``TimeResponseData``): what a
step added, its fitted values and errors, how it was judged, and its JSON.

A :class:`ChainStep` is one kept step of :func:`hil.ident.chain.diagnose_chain`. Its public fields
are the keys of ``chain[]`` in ``hil diagnose --json`` (docs/reference/json.md), in the same order;
:meth:`ChainStep.as_json` gives them, leaving out the optional ones a step does not have
(``swapped``, ``dropped``, ``estimation_error``, ``held_out``). The fits, the joint refit, the
config with the step and the first step's look-alike stay with the object for the code that goes on
from it (the EMPS table's rows, the swap) and never reach the JSON.

Read-only mapping access (``step["effects"]``, ``"held_out" in step``, ``step.get("dropped")``)
serves the code that reads a step beside the refused step's dict (``final.rejected``, a plain
mapping of the same keys); new code reads the attributes.

Channels are keyed by name (``x_motor``, ``force``, ...), errors are RMS in the channel's SI unit,
parameters in SI by effect (docs/reference/effects.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

__all__ = ["ChainStep"]

# the keys a step has only where it did that: a swap, an effect dropped, a held-out check
_OPTIONAL = ("swapped", "beyond_tolerance", "dropped", "nights_plant", "estimation_error", "held_out")


@dataclass
class ChainStep:
    """One kept step of the diagnosis chain.

    Parameters
    ----------
    step : int
        Its number, from 1 (a drift within the config's tolerance takes a number and is no step).
    effect : str
        The verdict of the step's diagnosis (a catalogue name or ``parameter:<key>``).
    effects : list of str
        What the step added: the verdict and the effects also missing beside it.
    params : dict
        Every effect the model holds after the step, its fitted parameters by name (SI).
    error_before, error_after : dict
        RMS error by channel before and after the step.
    gap_closed : dict
        By channel, the share of the gap to the noise floor the step closed.
    score : float
        The fall of the BIC the step earned (significant above ``MIN_SCORE``).
    evidence : str
        Where the verdict shows in the residual.
    refitted_together : bool
        Whether everything found so far was refitted together.
    stderr : dict
        The standard error of each fitted parameter (``effect.param``; None where at a bound).
    confounded : list
        Pairs of fitted parameters correlated above 0.9: ``[name, name, r]``.
    aliases : dict
        What a one-parameter step stands for (hil.ident.chain ``_aliases``).
    rival : dict or None
        The runner-up judged beside the verdict after the refit, and both scores.
    recording_artefacts : list of str
        The effects added that belong to the recording, not to the physics.
    swapped : str, optional
        The first step's verdict this step replaced (its look-alike fitted in its place).
    beyond_tolerance : dict, optional
        The step's diagnosis named a drift of the config that its tolerance does not explain (or an
        effect that the config's drift, the effects found refitted with it, brings to the noise
        floor), and the fit of every key left one key alone beyond the tolerance: the step is that
        key's candidate (hil.ident.chain ``_beyond_tolerance``): ``verdict`` (the diagnosis's),
        ``effect`` (the step's), ``key``, ``change`` (relative), ``tolerance`` and the fit's
        ``params`` (relative changes).
    dropped : list of dict, optional
        Effects found before that no longer paid for their parameters, with values and scores.
    nights_plant : dict, optional
        The step's effects with a grid refitted on the night's plant (hil.ident.chain
        ``_on_nights_plant``): ``effects``, ``tolerance``, the plant's ``params`` (config, value,
        change, standard error), the effects' ``stderr`` there, ``error_on_config_plant`` (the
        step's error before) and its ``held_out`` check; ``params`` and ``error_after`` are then the
        values and errors on the night's plant.
    estimation_error, held_out : dict, optional
        The errors on the data the step was fitted on and its check on the held-out data.
    fits, joint, config, runner_up
        The step's fits (hil.ident.fit.Candidate), the joint refit, the config with the step, the
        first step's look-alike: internal, not in the JSON.
    """
    step: int
    effect: str
    effects: list
    params: dict
    error_before: dict
    error_after: dict
    gap_closed: dict
    score: float
    evidence: str
    refitted_together: bool
    stderr: dict
    confounded: list
    aliases: dict
    rival: dict | None
    recording_artefacts: list
    swapped: str | None = None
    beyond_tolerance: dict | None = None
    dropped: list | None = None
    nights_plant: dict | None = None
    estimation_error: dict | None = None
    held_out: dict | None = None
    fits: list = field(default_factory=list, repr=False)
    joint: Any = field(default=None, repr=False)
    config: Any = field(default=None, repr=False)
    runner_up: Any = field(default=None, repr=False)

    def keys(self) -> list[str]:
        """The keys of its JSON, in order (the optional ones where the step has them)."""
        return [f.name for f in fields(self) if f.repr and not (f.name in _OPTIONAL and not getattr(self, f.name))]

    def as_json(self) -> dict:
        """The step as ``chain[]`` of ``hil diagnose --json``."""
        return {k: getattr(self, k) for k in self.keys()}

    def __getitem__(self, key: str):
        if key not in self.keys():
            raise KeyError(key)
        return getattr(self, key)

    def __contains__(self, key) -> bool:
        return key in self.keys()

    def get(self, key: str, default=None):
        return self[key] if key in self else default

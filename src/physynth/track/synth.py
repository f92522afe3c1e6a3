"""Synthetic training traces that vary the path and the anchor layout around a calibrated site.

The tracking study varies a calibrated scenario the way a scenario's own ``variation`` section does
(:class:`~physynth.models.variation.SiteVariationParams`, :mod:`physynth.models.variation`): the study's
variation takes the place of the scenario's section (:func:`with_variation`), and trace ``i`` is the
generator's trace ``i`` of that scenario, its site drawn from ``SeedSequence(root_seed, spawn_key=(i,
COMPONENT_ID["site"]))``. A study trace and a trace of the scenario with the same section are the same
by construction; the draws (a layout, jittered or whole; the path turned, shifted or replaced by a random
route; the NLOS frequency) are described in :mod:`physynth.models.variation`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..generate import CompiledScenario, compile_scenario, generate_trace
from ..models.variation import SiteVariationParams, random_route
from ..records import Trace
from ..scenario import Scenario

__all__ = ["random_route", "synthetic_trace", "with_variation"]


def with_variation(scn: Scenario, variation: SiteVariationParams | Mapping[str, Any] | None) -> Scenario:
    """``scn`` with ``variation`` as its ``variation`` section (replacing its own; None removes it),
    validated as a scenario file's section is."""
    section = variation.model_dump(mode="python") if isinstance(variation, SiteVariationParams) else variation
    return Scenario.model_validate({**scn.model_dump(mode="python"), "variation": section})


def synthetic_trace(scn: Scenario | CompiledScenario, index: int, root_seed: int,
                    variation: SiteVariationParams | Mapping[str, Any] | None = None) -> Trace:
    """Trace ``index`` of root seed ``root_seed``; with ``variation``, of ``scn`` with that variation section
    in place of its own (compile :func:`with_variation` once instead when drawing many traces)."""
    if variation is None:
        return generate_trace(scn, index, root_seed)
    base = scn.scenario if isinstance(scn, CompiledScenario) else scn
    return generate_trace(compile_scenario(with_variation(base, variation)), index, root_seed)

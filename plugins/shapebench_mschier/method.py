"""``msc-hier`` and ``msc-hier-noopt``: MSC (``shapebench_msc``) whose encoder reads each context
point's neighbourhood (:mod:`shapebench_mschier.network`).

Everything else is MSC's, unchanged: the posterior of equation 2 (a vote and a precision per
observation, summed), the ELBO of equation 3 with its context subsets, the IGR decoder, the
Eikonal and normal terms, the post-encoder optimisation of equation 6 (``msc-hier``) or the
posterior mean (``msc-hier-noopt``), and every option of MSC, with two more: ``neighbours`` (k)
and ``local_levels`` (rounds of neighbourhood pooling; 0 reduces the tower to a per-point MLP, the
paper's encoder up to its layer layout). Its trainings are its own (``checkpoint_family``).
"""

from __future__ import annotations

from dataclasses import dataclass

from shapebench_msc.method import MSCNoOpt, MSCOptions

from shapebench.api.options import option


@dataclass(frozen=True)
class MSCHierOptions(MSCOptions):
    neighbours: int = option(16, "k nearest context points each point's vote and precision read")
    local_levels: int = option(2, "rounds of neighbourhood pooling (0: a per-point MLP)")


class MSCHierNoOpt(MSCNoOpt):
    display_name = "MSC-hier (w/o opt)"
    description = "MSC with a hierarchical (local-neighbourhood) encoder, posterior mean"
    Options = MSCHierOptions
    checkpoint_family = "msc-hier"
    module_path = "shapebench_mschier.module:MSCHierModule"
    check_options = {**MSCNoOpt.check_options, "neighbours": 4, "local_levels": 1}


class MSCHier(MSCHierNoOpt):
    display_name = "MSC-hier (w/ opt)"
    description = "MSC with a hierarchical encoder and post-encoder latent optimisation (eq. 6)"
    optimise = True

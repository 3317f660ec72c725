"""Acceptance guidelines of identification and verification, each defined once.

Every threshold the library applies or reports (coherence admission, CIFER costs, parameter
accuracy, time-domain fit) lives here with its literature source; other modules import it.
The numbers are those the study has used all along; study-level choices that are not
guidelines (e.g. the forward-flight coherence admission) stay with the study.

References
----------
.. [TR] M. B. Tischler and R. K. Remple, *Aircraft and Rotorcraft System Identification:
   Engineering Methods with Flight-Test Examples*, 2nd ed., AIAA, 2012.
.. [J] R. V. Jategaonkar, *Flight Vehicle System Identification: A Time-Domain
   Methodology*, 2nd ed., AIAA, 2015.
"""

from __future__ import annotations

__all__ = ["COHERENCE_MIN", "CROSS_COHERENCE_MAX", "J_AVE_MAX", "J_PAIR_MAX",
           "CR_MAX_PERCENT", "INSENSITIVITY_MAX_PERCENT", "UNDETERMINED_PERCENT",
           "COST_INCREASE_MAX",
           "BIAS_BOUNDS_MAX", "J_RMS_MAX", "TIC_MAX", "FIT_TIME_LIMIT_S", "GAP_MIN_STEPS",
           "GAP_MAX_STEPS", "GUIDELINES", "REDUCTION_GUIDELINES"]

# -- frequency responses ---------------------------------------------------------------------
#: Coherence gamma^2 above which a frequency point is accurate enough to fit and to judge
#: ([TR] coherence guideline gamma^2 >= 0.6 for the fitted range).
COHERENCE_MIN = 0.6
#: Mean cross-control coherence below which the controls are uncorrelated enough for a
#: well-conditioned MIMO identification ([TR], multi-input conditioning, about 0.5).
CROSS_COHERENCE_MAX = 0.5

# -- frequency-domain fit (CIFER cost) -------------------------------------------------------
#: Average cost over the pairs ([TR] J_ave <= 100: acceptable for flight-dynamics modelling).
J_AVE_MAX = 100.0
#: Cost of every single input/output pair ([TR] J <= 150-200; the study uses the upper end).
J_PAIR_MAX = 200.0

# -- parameter accuracy and model-structure reduction -----------------------------------------
#: Cramer-Rao bound, % of |value| ([TR] CR <= 20 %).
CR_MAX_PERCENT = 20.0
#: Insensitivity, % of |value| ([TR] I <= 10 %).
INSENSITIVITY_MAX_PERCENT = 10.0
#: Cramer-Rao bound, % of |value|, at which the data no longer fix an estimate's sign: the
#: parameter is undetermined, whatever the structure keeps it for (e.g. a hybrid's slow-mode
#: speed terms when their responses lack coherence). Tables and the report list such
#: parameters (a project choice: one standard deviation reaching zero).
UNDETERMINED_PERCENT = 100.0
#: Largest rise of the cost (units of J_ave) a parameter's removal may cause in the stepwise
#: reduction ([TR] model-structure reduction: removals must leave the cost nearly unchanged).
COST_INCREASE_MAX = 2.0
#: An estimate further from a known truth than this many of its (one-sigma) bounds is biased
#: beyond what the noise explains: a structure or data problem, not noise (the fidelity
#: scoreboard of sysid.assess.comparison; 3 sigma: an unbiased Gaussian estimate lands
#: beyond it with probability 0.3 %; a project choice, docs/methods.md, "Accuracy").
BIAS_BOUNDS_MAX = 3.0

# -- time-domain verification ----------------------------------------------------------------
#: Weighted rms output error with unit weights per ft/s, deg/s, deg ([TR] J_rms <= 1-2
#: acceptable; the upper end).
J_RMS_MAX = 2.0
#: Theil's inequality coefficient ([J] TIC <= 0.25-0.3: good predictive capability; the
#: lower end).
TIC_MAX = 0.25

# -- iterative fits ---------------------------------------------------------------------------
#: Wall-clock bound (s) of one identification (fit, restarts and model reduction) in either
#: domain; a fit that needs more is stopped with a message (not a guideline: a safety bound,
#: well above the hover study's fits, which take tens of seconds and took 198 s on an
#: overloaded 2-core machine, see sysid.core.util.blas_threads). Each least-squares solve is
#: also bounded in iterations (``max_nfev``, scipy's default 100 per parameter).
FIT_TIME_LIMIT_S = 1800.0

# -- resampling of imported records (sysid.data.resample) -----------------------------------
#: A step between two samples longer than this many typical steps is a gap: at least one
#: sample is missing. Clock jitter below +-50 % of the step on every sample stays below it;
#: a missing sample reaches it. (A project choice, docs/methods.md, "Resampling imported
#: records".)
GAP_MIN_STEPS = 2.0
#: Longest gap, in typical steps, that resampling bridges by interpolation; a longer one
#: splits the record into two manoeuvres. The cubic spline across a gap of length T departs
#: from a component of angular frequency w by at most 5 (w T)^4 / 384 of its amplitude
#: (the spline's error bound, [B78] in docs/methods.md): at 4 steps
#: and the top of the identification band (about 20 rad/s) 0.5 % for a 100 Hz record,
#: 8.5 % for 50 Hz, on a few samples of thousands; longer bridges would put made-up data
#: into the spectra and fits (a project choice; same section).
GAP_MAX_STEPS = 4.0

#: The guidelines by the names the HTML report shows them under.
GUIDELINES = {
    "J_ave": J_AVE_MAX,
    "pair_J": J_PAIR_MAX,
    "cramer_rao_percent": CR_MAX_PERCENT,
    "insensitivity_percent": INSENSITIVITY_MAX_PERCENT,
    "j_rms": J_RMS_MAX,
    "tic": TIC_MAX,
    "coherence": COHERENCE_MIN,
    "cross_coherence": CROSS_COHERENCE_MAX,
}

#: The guidelines as the keyword defaults of the stepwise reduction (identify.reduction).
REDUCTION_GUIDELINES = {"cr_max": CR_MAX_PERCENT, "insensitivity_max": INSENSITIVITY_MAX_PERCENT,
                        "max_cost_increase": COST_INCREASE_MAX}

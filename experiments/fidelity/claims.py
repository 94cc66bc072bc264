"""The inventory of what the five source documents claim, and how jaxdip decides each claim.

One ``Claim`` per numbered table, per figure with a quantitative message and per numeric claim in the prose of
the paper (Bernstein, King, Tran), King's thesis (ch. 1-4), Stumfoll's thesis and Aranovskiy et al.; figures with
nothing to score are listed once in ``QUALITATIVE``. ``experiments/fidelity/index.py`` turns this list, the
readings rows ``docs/fidelity/*.json`` and the ``metrics.json`` of experiment runs into ``docs/fidelity.md``.

A claim's status is decided in one of these ways (in this order of precedence):

- ``readings=True``: rows of the readings studies (the studies in ``experiments/fidelity/`` write ``docs/fidelity/<name>.json``,
  one row per reading with ``holds`` yes/no/undecided) under the claim's id. No rows yet: "readings pending" (and
  the default run's checks, if any, are shown beside it).
- ``checks``: ``Check``s on the ``results`` of ``jaxdip run <experiment>`` (``metrics.json``), each with the
  document's number and a stated rule (relative tolerance, the document's value inside our 95% interval, one
  interval entirely below another, a threshold). All hold: reproduced; one fails: not reproduced; else undecided.
- ``test``: checked by the named test against an independent reference, not by a run's number.
- ``input``: a table of parameters the models use; nothing to reproduce.
- ``not_attempted``: why not.

A claim that holds is classed by how far it departs from the text (``experiments/fidelity/index.py`` states the
rules at the top of ``docs/fidelity.md``): ``choices`` name the modelling choices a default-config verdict depends
on, each with its support and the number without it; ``ordering`` marks a claim checked only as an ordering on
a metric we chose; readings rows get their support from ``experiments/fidelity/support.py``.

Claim ids: ``<doc>:<kind>-<number>[<suffix>]`` with the document's own numbering; kind ``claim`` plus a slug for
a number in the prose. Tolerances are ours (the documents state none); each ``Check`` says its rule.
"""

from __future__ import annotations

from experiments.fidelity.claim_types import (  # noqa: F401  (re-exported: the inventory's API)
    DOCUMENTS, RULES, SUPPORT, Check, Choice, Claim, Qualitative, _below)
from experiments.fidelity import claims_propositions as _propositions
from experiments.fidelity import claims_twip as _twip

# --------------------------------------------------------------------------------------------------------------
# the checks shared by the paper's Table 1 and the thesis's Table 3.2 (the same laboratory table, printed twice)
_CPX_LDF = tuple(
    _below("dip-cpx-ldf", f"cpx/{s}_var", f"ldf/{s}_var", f"{s} variance: CPX below LDF ({u})")
    for s, u in (("xc", "cm^2"), ("alpha", "deg^2"), ("theta", "deg^2"))
) + tuple(
    _below("dip-cpx-ldf", f"cpx/{s}_abs_trial_mean_{u}", f"ldf/{s}_abs_trial_mean_{u}",
           f"|trial mean of {s}|: CPX below LDF ({u})")
    for s, u in (("xc", "cm"), ("alpha", "deg"), ("theta", "deg"))
)
_TABLE1_NUMBERS = ("lab, one run each: CPX xc mean -0.002 cm var 5.52 cm^2, alpha .178 deg / 35.2 deg^2, theta "
                   "-.45 deg / 3.89 deg^2; LDF -0.119 / 5.98, 1.21 / 41.8, -.867 / 6.78")
_GAMMA = Check("dip-cpx-ldf", "close", "gamma_criterion/gamma", "gamma criterion of Prop. 1.4.3 at 1 ms (outputs "
               "xc, alpha, theta), within 1% of 24400", value=24400.0, tol=0.01)
# Table 3.3 lists Mw; the printed equations of §3.1.1 never use it; the default puts it on the cart
_MW = Choice("Mw on the cart", "contradicts", "the cart's mass in the printed equations of §3.1.1 leaves out "
             "Table 3.3's extra weight Mw", "29148 with the equations as printed (19% above 24400)",
             key="gamma_criterion/gamma_without_Mw")
# chapter 4 prints its formulas and theorem for any parameters; the checks run them at ours
_IFN = Choice("parameters of our choosing (R0 = 3)", "supported", "ch. 4 prints no parameter values",
              "not run at other parameters")
_OSC_ORDERING = ("theta_dot RMS error at two gamma pairs only; the printed 'large amplitude high frequency "
                 "oscillations' are not measured, and the RMS error over the gamma sweep is not monotone (it falls "
                 "from gamma 1 to about 5600, below the criterion, and rises only past it)")
_GAMMA_OSC = (
    _below("dip-cpx-ldf", "velocity_trial/theta_dot_rms_err_cpx", "velocity_trial/theta_dot_rms_err_cpx_criterion",
           "theta_dot RMS error (rad/s), seed 0: gamma 150 below gamma at the criterion"),
    _below("dip-cpx-ldf", "gamma_sweep/theta_dot_rms_err/0", "gamma_sweep/theta_dot_rms_err/-1",
           "theta_dot RMS error (rad/s) of the gamma sweep: gamma 1 below gamma 1e5"),
)

_CLAIMS_DIP: list[Claim] = [
    # ---------------------------------------------------------------------------------------------- paper
    Claim("paper:table-1", "§5, Table 1 (6.5 s of stabilisation, laboratory DIP)",
          "Power-series control fed by CPX (gamma 150) keeps the DIP closer to upright and with less variance in "
          "every measured state than fed by Quanser's low-pass derivative filter (LDF).",
          _TABLE1_NUMBERS, exp="dip-cpx-ldf",
          keys="dip-cpx-ldf readings (weight reading of (9)/(3.7), disturbance, encoder resolution, actuator "
               "nonlinearities)", checks=_CPX_LDF, readings=True,
          notes="Laboratory numbers; the simulation can decide the ranking, not the lab's scale."),
    Claim("paper:table-1-scale", "§5, Table 1, the printed variances themselves",
          "The magnitudes of Table 1's variances (laboratory), which the simulation's are 10^2-10^3x below; the "
          "readings ask whether unmodelled cart friction, deadzone or backlash bring both estimators to them.",
          _TABLE1_NUMBERS, exp="dip-cpx-ldf",
          keys="dip-cpx-ldf readings (deadzone, backlash, cart_coulomb, disturbance)", readings=True,
          notes="The friction/backlash explanation is ours, not the paper's."),
    Claim("paper:prop-1", "§2, Proposition 1", "The proximal observer's error obeys "
          "e_{k+1} = Phi U Lbar U^T e_k + Phi U Lddot U^T zeta_k - eta_k.", "an identity (no number)",
          test="tests/test_theory_mhe.py::test_prop_1_4_2_cpx_and_1_5_1_scpx (same recursion as thesis Prop. 1.4.2)"),
    Claim("paper:prop-2", "§2, Proposition 2 and §5 'gamma >= 24400 for the DIP system'",
          "With fixed gamma > (||Phi|| - 1)/lambda_min the estimate error stays bounded; for the DIP this asks for "
          "gamma >= 24400.", "24400", exp="dip-cpx-ldf", keys="dip-cpx-ldf (gamma_criterion)", checks=(_GAMMA,),
          choices=(_MW,)),
    Claim("paper:claim-5-gamma-oscillation", "§5, last paragraph",
          "With gamma above the criterion the CPX velocity estimates oscillate with large amplitude at high "
          "frequency, unusable for control; gamma had to be lowered by two orders of magnitude (to 150-ish).",
          "gamma 24400 -> ~244 (two orders); lab observation", exp="dip-cpx-ldf",
          keys="dip-cpx-ldf (gamma_sweep, velocity_trial)", checks=_GAMMA_OSC, ordering=_OSC_ORDERING,
          notes="Simulation: the loop still stabilises past the criterion; only the estimate error grows."),
    # ---------------------------------------------------------------------------------------------- thesis ch. 1
    Claim("thesis:thm-1.3.2", "§1.3, Theorem 1.3.2",
          "The proximal point MHE with weights gamma_k growing as the theorem asks converges for nonlinear "
          "fitting functionals (the two-measurement functional (1.9) as the example).", "a theorem (no number)",
          keys="fid-dip readings study", readings=True,
          notes="Not attempted before issue 16."),
    Claim("thesis:prop-1.4.1", "§1.4, Proposition 1.4.1",
          "With gamma_k as in Theorem 1.3.2 the least-squares proximal observer (1.10) converges.",
          "a proposition (no number)", keys="fid-dip readings study", readings=True),
    Claim("thesis:prop-1.4.2", "§1.4, Proposition 1.4.2", "Error recursion of the proximal observer (as paper "
          "Prop. 1).", "an identity", test="tests/test_theory_mhe.py::test_prop_1_4_2_ltv_horizon"),
    Claim("thesis:prop-1.4.3", "§1.4, Proposition 1.4.3; §3.3 'gamma >= 24400 for the DIP system'",
          "Fixed gamma above (||Phi|| - 1)/lambda_min bounds the error by kappa/(1 - r); 24400 for the DIP.",
          "24400", exp="dip-cpx-ldf", keys="dip-cpx-ldf (gamma_criterion)", checks=(_GAMMA,), choices=(_MW,),
          notes="The bound itself: tests/test_theory_mhe.py::test_prop_1_4_3_bound_1000_seeds."),
    Claim("thesis:prop-1.5.2", "§1.5.2, Proposition 1.5.2", "Stability of the subspace (SCPX) estimates.",
          "a proposition", test="tests/test_propositions_mhe.py::test_prop_1_5_2_subspace_bound"),
    Claim("thesis:fig-1.1-norm", "§1.6, Fig. 1.1 and 'Both proximal point methods had smaller estimation error "
          "than the EKF'", "Over 50 Lorenz trials (h = 0.001, 20 time units, sigma_eta 0.1, sigma_eps 5) CPX "
          "(gamma 0.5) and SCPX (gamma 50) have a smaller mean norm error e than an EKF with the true noise.",
          "ordering only (Fig. 1.1); no number printed", exp="lorenz-mhe",
          keys="lorenz-mhe: eps_reading, eta_reading, ekf_eta_time, eta_time, alignment",
          checks=tuple(_below("lorenz-mhe", f"{m}/mean_norm_error", "ekf/mean_norm_error", f"e: {m.upper()} below EKF")
                       for m in ("cpx", "scpx")), readings=True),
    Claim("thesis:fig-1.1-xL", "§1.6, Fig. 1.1 and 'the SCPX had the smallest estimation error of the unmeasured "
          "state variable x_L'", "SCPX has the smallest mean x_L error of the four estimators.",
          "ordering only (Fig. 1.1)", exp="lorenz-mhe", keys="as thesis:fig-1.1-norm",
          checks=tuple(_below("lorenz-mhe", "scpx/mean_xL_error", f"{m}/mean_xL_error", f"e_xL: SCPX below "
                              f"{m.upper()}") for m in ("cpx", "ekf", "ekf2")), readings=True),
    Claim("thesis:claim-1.6-ekf2", "§1.6, 'the noise parameters were tuned for a better fit of the unmeasured state "
          "variable x_L, the best parameters found were sigma_eta = .005 and sigma_eps = 10'",
          "EKF2 (sigma_eta 0.005, sigma_eps 10) fits x_L better than the EKF with the true noise levels.",
          "0.005, 10 (no error printed)", exp="lorenz-mhe", keys="as thesis:fig-1.1-norm",
          checks=(_below("lorenz-mhe", "ekf2/mean_xL_error", "ekf/mean_xL_error", "e_xL: EKF2 below EKF"),),
          readings=True),
    Claim("thesis:fig-1.2", "§1.6, Fig. 1.2", "SCPX recovers the extrema of x_L's oscillations more closely than the "
          "EKF.", "visual (Fig. 1.2)", exp="lorenz-mhe", keys="as thesis:fig-1.1-norm",
          checks=(_below("lorenz-mhe", "scpx/mean_xL_error_at_extrema", "ekf/mean_xL_error_at_extrema",
                         "x_L error where |x_L| > 15: SCPX below EKF"),), readings=True),
    # ---------------------------------------------------------------------------------------------- thesis ch. 2
    Claim("thesis:prop-2.4.2", "§2.4, Proposition 2.4.2", "The continuous relaxed projection control (2.14) is "
          "globally exponentially stable when gamma(t) > zeta for all t.", "a proposition",
          keys="fid-dip readings study", readings=True, notes="Not attempted before issue 16."),
    Claim("thesis:procedure-1", "§2.6.4, Procedure 1; §3.2.1 'N(0, 5 x 10^-5)'",
          "The ensemble Kalman search (2.21)-(2.24) finds a stabilising P; on the DIP with state noise "
          "N(0, 5e-5) every 1 ms and one initial state per member.", "5e-5 (std or variance not said)",
          exp="eki-dip", keys="eki-dip readings (noise as std or variance, x0 per member)",
          checks=(Check("eki-dip", "ge", "judge/stabilized_fraction", "stabilised fraction of RP (gamma 40) with "
                        "the found P, at least 0.95", value=0.95),), readings=True),
    Claim("thesis:claim-2.7.1-v", "§2.7.1, 'after about 150 iterations the ensemble mean was' v = [-.9975, -.07]",
          "On the linear example the search (J = 50, K = 8) ends at a stabilising v close to [-0.9975, -0.07].",
          "v = [-0.9975, -0.07], ~150 iterations", exp="eki-linear", keys="eki-linear",
          checks=(Check("eki-linear", "true", "stabilizing", "found P stabilising"),
                  Check("eki-linear", "ge", "stabilizing_fraction", "fraction of search seeds ending stabilising, "
                        "at least 0.9", value=0.9),
                  Check("eki-linear", "ge", "alignment_with_thesis_v", "|cos| between our v and the thesis's, at "
                        "least 0.99", value=0.99))),
    Claim("thesis:fig-2.1", "§2.7.1, Fig. 2.1-2.2 and 'slower than the LQR control to bring the system near the "
          "origin ... transitions to a faster convergence rate once near'",
          "From x0 = [2, 1], relaxed projection is slower than the LQR to come near the origin and then converges "
          "faster.", "visual (Fig. 2.1-2.2)", exp="eki-linear", keys="eki-linear (steps_to_reach)",
          checks=(Check("eki-linear", "ratio_ge", "steps_to_reach/1/rp", "steps to ||x|| < 1: RP at least the "
                        "LQR's (slower to come near)", value=1.0, other="steps_to_reach/1/lqr"),
                  _below("eki-linear", "steps_to_reach/0.01/rp", "steps_to_reach/0.01/lqr",
                         "steps to ||x|| < 1e-2: RP fewer than the LQR")),
          choices=(Choice("our search's v, and the thesis's gamma kept", "contradicts", "§2.7.1 tuned gamma so that "
                          "RP's largest |u| matched the LQR's", "not measured with a matched gamma; with ours RP's "
                          "largest |u| is several times the LQR's (max_abs_u in metrics.json: 140-158 vs 20 in --quick)"),),
          notes="The thesis tuned gamma so that RP's largest |u| matched the LQR's for its v; we keep its gamma, "
                "so with our v RP's largest |u| is larger (max_abs_u in metrics.json). The quick run's one search "
                "ends where rounding takes it: compiled at another XLA optimisation level, its steps to ||x|| < 1 "
                "went from 24 to 14 (the first check flips), so this row is as fragile as one search."),
    Claim("thesis:fig-2.2", "§2.7.1, Fig. 2.2 (log scale)", "The relaxed projection's convergence rate grows as the "
          "state nears the origin (superlinear on the log plot), the LQR's stays constant.", "visual",
          exp="eki-linear", keys="eki-linear (steps_to_reach)",
          checks=(_below("eki-linear", "steps_to_reach/0.0001/rp", "steps_to_reach/0.01/lqr",
                         "steps to ||x|| < 1e-4 by RP below the LQR's steps to 1e-2"),),
          ordering="the convergence rates are compared through steps to two radii, not through the slope of Fig. "
                   "2.2's log plot"),
    Claim("thesis:claim-2.7.2-v", "§2.7.2, 'after about 250 iterations the ensemble mean was' v = [.995, .1003]",
          "On the nonlinear example the search (J = 100, K = 4) ends at a stabilising v close to [0.995, 0.1003].",
          "v = [0.995, 0.1003], ~250 iterations", exp="eki-nonlinear",
          keys="eki-nonlinear (x0_draw, final, R, init_var, iterations, K, judge_std); experiments.fidelity.dip_search.eki_nonlinear",
          checks=(Check("eki-nonlinear", "true", "stabilizing", "found P stabilising"),
                  Check("eki-nonlinear", "ge", "stabilizing_fraction_single_ensemble", "searches with one ensemble "
                        "(the thesis's procedure) ending stabilising, at least 0.9", value=0.9),
                  Check("eki-nonlinear", "ge", "alignment_with_thesis_v", "|cos| with the thesis's v, at least "
                        "0.99", value=0.99)), readings=True),
    Claim("thesis:fig-2.3", "§2.7.2, Fig. 2.3", "Relaxed projection with the found P stabilises the nonlinear "
          "example smoothly.", "visual", exp="eki-nonlinear", choices=(Choice(
              "our search's P", "unprinted", "Fig. 2.3 uses the P of the printed v = [.995, .1003]", "not run with "
              "the printed v (our searches end there in about half the cases: thesis:claim-2.7.2-v)"),), keys="eki-nonlinear",
          checks=(Check("eki-nonlinear", "ge", "stabilized_fraction_of_initial_states", "random initial states "
                        "brought below 1e-3, at least 0.99", value=0.99),)),
    # ---------------------------------------------------------------------------------------------- thesis ch. 3
    Claim("thesis:table-3.3", "§3.1.1, Table 3.3", "Parameters of the Quanser DIP.", "the table", input=True),
    Claim("thesis:claim-3.2.1-one-vector", "§3.2.1, 'P using one free basis vector could be found which were "
          "stabilizing in a neighborhood of the origin for simulations'",
          "The search with one free vector (singular value fixed at 1e6) finds P stabilising near upright in "
          "simulation.", "s = 1e6", keys="fid-dip readings study", readings=True,
          notes="Not attempted before issue 16."),
    Claim("thesis:claim-3.2.1-search", "§3.2.1, 'J = 80 for a maximum of 1000 iterations ... gamma = 10'",
          "The two-vector search finds a P (3.6) that stabilises the DIP model.", "J = 80, 1000 iterations",
          exp="eki-dip", keys="eki-dip", choices=(Choice(
              "state noise 5e-5 read as a standard deviation", "supported", "§3.2.1's N(0, 5 x 10^-5) does not say "
              "std or variance", "read as a variance no search stabilises (thesis:procedure-1 rows: 0 of 200)"),),
          checks=(Check("eki-dip", "ge", "judge/stabilized_fraction", "RP (gamma 40) with the found P from random "
                        "states, at least 0.95", value=0.95),
                  Check("eki-dip", "le", "performance/failed", "failed held-out performance runs, none",
                        value=0.0))),
    Claim("thesis:eq-3.6", "§3.2.1, (3.6): v1, v2, s = [9.99e5, 3.37e4]",
          "The published P with relaxed projection (2.14), gamma = 40, stabilises the DIP (Fig. 3.3 simulation, "
          "Table 3.1 laboratory). Readings decide it by local (linearised) stability at upright.",
          "stabilising (no eigenvalue printed)", exp="dip-controllers",
          keys="dip-controllers: variant, Mw, published_P_order, published_P_flip, published_P_angles, "
               "published_P_units, published_P_construction, rp_gamma",
          checks=(Check("dip-controllers", "true", "published_P/linearised_stable", "linearised closed loop with "
                        "(3.6) stable (default reading)"),), readings=True,
          notes="Rows: the readings changed one at a time and the ten best of the 384 groups of "
                "docs/fidelity/published_p.md (4 of all 1536 combinations, one group, are stable). Locally stable "
                "is not the thesis's claim in full: that reading kept 20 of 32 seeds up in a 2 s --quick run and "
                "fell from the thesis's x0 (README, dip-controllers)."),
    Claim("thesis:fig-3.3", "§3.2.2, Fig. 3.3 (simulation from x0 = [.0192, .0025, .0287, -.0392, -.004, -.0242])",
          "All three controls stabilise the model from the thesis's x0; RP has the largest control effort.",
          "visual", exp="dip-controllers", keys="dip-controllers",
          checks=(*(Check("dip-controllers", "true", f"{c}/from_thesis_x0/stabilized", f"{c.upper()} stabilises "
                          "from the thesis's x0") for c in ("lqr", "ps", "rp")),
                  _below("dip-controllers", "lqr/from_thesis_x0/max_abs_u", "rp/from_thesis_x0/max_abs_u",
                         "max |u| (V): LQR below RP (library P)")),
          choices=(Choice("the library's P in RP", "unprinted", "§3.2.2 simulates RP with (3.6)", "with (3.6) as "
                          "printed RP does not stabilise the printed model at all (thesis:eq-3.6)"),),
          notes="RP here uses the library's P; the published P does not stabilise the model (thesis:eq-3.6)."),
    Claim("thesis:table-3.1", "§3.2.2, Table 3.1 (laboratory, a typical 20 s)",
          "RP keeps the smallest mean |state| and variance of every state; its mean |u| is almost twice the "
          "LQR's and PS's, its variance more than twice.",
          "mean/var LQR, PS, RP: |alpha| 3.4/3.03, 1.8/1.1, 1.4/.85; |theta| 1.9/.81, .9/.35, .46/.09; |xc| "
          "29.4/410.7, 36.5/639.4, 23.4/285.1; |u| 1.7/1.5, 1.8/2.9, 2.5/5.0 (units not printed)",
          exp="dip-controllers", keys="dip-controllers readings (state variances, the published P where stable)",
          checks=(*(_below("dip-controllers", f"rp/states/{s}/mean_abs", f"lqr/states/{s}/mean_abs",
                           f"mean |{s}|: RP below LQR") for s in ("alpha", "theta", "xc")),
                  Check("dip-controllers", "ratio_ge", "rp/u/mean_abs", "mean |u|: RP at least 1.3x the LQR's "
                        "(document 2.5/1.7 = 1.47)", value=1.3, other="lqr/u/mean_abs"),
                  Check("dip-controllers", "ratio_ge", "rp/u/var", "var u: RP at least 2x the LQR's (document "
                        "5.0/1.5 = 3.3)", value=2.0, other="lqr/u/var")),
          readings=True, notes="Simulation with the library's P; laboratory magnitudes are not expected."),
    Claim("thesis:table-3.2", "§3.3, Table 3.2 (= paper Table 1)", "As paper:table-1.", _TABLE1_NUMBERS,
          exp="dip-cpx-ldf", keys="as paper:table-1", checks=_CPX_LDF, readings=True),
    Claim("thesis:table-3.2-scale", "§3.3, Table 3.2, the printed variances themselves",
          "As paper:table-1-scale.", _TABLE1_NUMBERS, exp="dip-cpx-ldf", keys="as paper:table-1-scale",
          readings=True),
    Claim("thesis:claim-3.3-gamma-oscillation", "§3.3, last paragraph (= paper §5)",
          "As paper:claim-5-gamma-oscillation.", "gamma 24400 -> two orders lower", exp="dip-cpx-ldf",
          keys="dip-cpx-ldf (gamma_sweep, velocity_trial)", checks=_GAMMA_OSC, ordering=_OSC_ORDERING),
    Claim("thesis:claim-3.3-ekf", "§3.3, 'an extended Kalman filter was not able to supply state estimates to a "
          "power-series controller such that the system could be stabilized even in simulations'",
          "Bernstein's EKF-fed power-series control fails on the noisy nonlinear DIP model.", "no number",
          not_attempted="no EKF-fed DIP loop is built; the claim cites Bernstein's thesis, not this work's "
                        "results"),
    # ---------------------------------------------------------------------------------------------- thesis ch. 4
    Claim("thesis:eq-4.4", "§4.3.1, (4.1)-(4.4)", "E[I] = R0 - integral of g over the protected set; R0 = "
          "beta gamma/(eta (gamma + delta)).", "formulas (R0 = 3 with our parameters)", exp="ifn-protection", choices=(_IFN,),
          keys="ifn-protection", checks=(
              Check("ifn-protection", "true", "model/R0_in_ci", "R0 formula inside the Monte Carlo 95% interval"),
              Check("ifn-protection", "true", "model/E_Z_in_ci", "E[Z] = beta/eta inside the interval"),
              Check("ifn-protection", "true", "controls_mc/level set, uniform h/quadrature_in_ci",
                    "E[I] of the uniform-cost level set: (4.4) inside the interval"))),
    Claim("thesis:thm-4.4.1", "§4.4.1, Theorem 4.4.1", "The optimal protected set is the upper level set of g/h "
          "at r-bar: no other set with the same E[I] costs less.", "a theorem", exp="ifn-protection", choices=(_IFN,),
          keys="ifn-protection",
          checks=tuple(Check("ifn-protection", "true", f"theorem/{h}/level_set_cheapest", f"{h} cost: level set "
                             "cheaper than every tuned competitor") for h in ("uniform", "distance", "shell"))),
    Claim("thesis:claim-4.4-F", "§4.4.1, (4.7)-(4.8)", "F(r) is nonincreasing (and upper semi-continuous); r-bar "
          "is where it crosses V.", "properties", exp="ifn-protection", choices=(_IFN,), keys="ifn-protection",
          checks=tuple(Check("ifn-protection", "true", f"F_properties/{h}/nonincreasing_within_brackets",
                             f"F nonincreasing ({h} cost)") for h in ("uniform", "distance", "shell", "flat"))),
    Claim("thesis:claim-4.4.2-corollary", "§4.4.1, Corollary 4.4.2 and the non-unique case",
          "The level set is the unique optimum when F(r-bar) = V; otherwise many sets are optimal.",
          "no number", exp="ifn-protection", choices=(_IFN,), keys="ifn-protection (flat_case)",
          checks=(Check("ifn-protection", "false", "flat_case/unique", "the flat-ratio case is not unique"),
                  Check("ifn-protection", "close", "flat_case/sets/flat set after t_c/h", "a second optimal set "
                        "costs V/r-bar (1e-6 relative)", other="flat_case/optimal_cost_V_over_r_bar", tol=1e-6))),
    Claim("thesis:claim-4.5-autonomous", "§4.5, biologically feasible (cell-autonomous) control",
          "A cell-autonomous rule can realise the optimal protection as a threshold on the local signal.",
          "no number", not_attempted="no scored metric: implemented in jaxdip.immune (docs/immune.md) without a "
                                     "results key to compare"),
]
# Stumfoll and Aranovskiy et al. are in experiments/fidelity/claims_twip.py; the numbered propositions and
# theorems of the documents in experiments/fidelity/claims_propositions.py
CLAIMS: list[Claim] = _CLAIMS_DIP + list(_twip.CLAIMS) + list(_propositions.CLAIMS)


QUALITATIVE: list[Qualitative] = [
    Qualitative("paper:fig-1", "diagram and photograph of the DIP"),
    Qualitative("paper:fig-2", "laboratory CPX and LDF estimates of theta-dot (the two differ most there)"),
    Qualitative("thesis:fig-3.1", "diagram of the DIP"),
    Qualitative("thesis:fig-3.2", "photograph of the laboratory DIP"),
    Qualitative("thesis:fig-3.4", "laboratory traces of RP, PS and LQR over 0.5 s (RP more oscillatory; numbers "
                                  "in Table 3.1)"),
    Qualitative("thesis:fig-3.5", "laboratory CPX and LDF estimates of theta-dot (= paper Fig. 2)"),
    Qualitative("stumfoll:fig-4.1", "photograph of the TWIP robot"),
    Qualitative("stumfoll:fig-5.1", "DC motor model diagram"),
    Qualitative("stumfoll:fig-5.2", "wheel free-body diagram"),
    Qualitative("stumfoll:fig-5.3", "pendulum free-body diagram"),
    Qualitative("stumfoll:fig-5.4", "uncontrolled start at 180 deg stays put (an equilibrium check)"),
    Qualitative("stumfoll:fig-7.2", "saturation nonlinearity"),
    Qualitative("stumfoll:fig-7.3", "deadzone nonlinearity"),
    Qualitative("stumfoll:fig-7.4", "deadzone with jumps"),
    Qualitative("stumfoll:fig-7.5", "backlash nonlinearity"),
    Qualitative("stumfoll:fig-8.1", "states, no noise, no uncertainty"),
    Qualitative("stumfoll:fig-8.4", "uncertainty estimates, nominal (its 25% is stumfoll:claim-8.1.1-25pct)"),
    Qualitative("stumfoll:fig-8.5", "states with parameter uncertainty (its 5 deg is stumfoll:claim-8.1.2-5deg)"),
    Qualitative("stumfoll:fig-8.8", "uncertainty estimates with parameter uncertainty (anomaly at 1.5 s)"),
    Qualitative("stumfoll:fig-8.12", "states with noise and uncertainty"),
    Qualitative("stumfoll:fig-8.14", "uncertainty estimates with noise ('on the order of the measurement noise')"),
    Qualitative("stumfoll:fig-8.15", "extra-control states, parameter uncertainty (scored in Table 8.3)"),
    Qualitative("stumfoll:fig-8.16", "extra-control signals, parameter uncertainty"),
    Qualitative("stumfoll:fig-8.17", "extra-control states, unmodeled dynamics (scored in Table 8.3)"),
    Qualitative("stumfoll:fig-8.19", "extra-control signals, unmodeled dynamics"),
    Qualitative("stumfoll:fig-8.20", "extra-control states, deadzone (scored in Table 8.3)"),
    Qualitative("stumfoll:fig-8.21", "extra-control signals, deadzone"),
    Qualitative("stumfoll:fig-8.22", "extra-control states, deadzone and backlash (scored in Table 8.3)"),
    Qualitative("stumfoll:fig-8.23", "extra-control signals, deadzone and backlash"),
    Qualitative("stumfoll:fig-8.24", "robot states (hardware; see stumfoll:sec-8.3)"),
    Qualitative("stumfoll:fig-8.25", "robot states, close-up (hardware)"),
    Qualitative("stumfoll:fig-8.26", "complementary filter against raw accelerometer tilt (hardware)"),
    Qualitative("stumfoll:fig-8.27", "robot uncertainty estimates (hardware)"),
    Qualitative("aranovskiy:fig-1", "the AnyWalker robot"),
    Qualitative("aranovskiy:fig-2", "pendulum hardware and notation"),
    Qualitative("aranovskiy:fig-4", "biased loop traces (its numbers are aranovskiy:eq-15 and eq-16)"),
]


def by_id() -> dict[str, Claim]:
    out: dict[str, Claim] = {}
    for c in CLAIMS:
        if c.id in out:
            raise ValueError(f"claim id {c.id} twice")
        out[c.id] = c
    return out


def all_ids() -> set[str]:
    """Every id the inventory knows (scored claims and qualitative figures)."""
    ids = set(by_id())
    q = {x.id for x in QUALITATIVE}
    if ids & q:
        raise ValueError(f"ids both scored and qualitative: {sorted(ids & q)}")
    return ids | q

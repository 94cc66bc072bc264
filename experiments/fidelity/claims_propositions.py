"""The numbered propositions, lemmas, theorems and corollaries of the four documents that
``claims.CLAIMS`` does not already hold, each checked by a test or marked not attempted with why.

``NUMBERED`` lists every numbered result of the documents (definitions, assumptions and remarks are not claims;
Aranovskiy's "Theorem 10" is a result of its reference [14], not of the paper) with the id of the row that
decides it, here or in ``claims``; ``tests/test_fidelity_propositions.py`` checks that each id has
exactly one row and that every test a row here names exists.

``claims`` appends ``CLAIMS`` to its own list.
"""

from __future__ import annotations

from experiments.fidelity.claim_types import Claim

_MHE = "tests/test_propositions_mhe.py"
_PROJ = "tests/test_propositions_projection.py"
_RWP = "tests/test_propositions_rwp.py"
_DMSO = "tests/test_propositions_stumfoll.py"

NUMBERED: tuple[str, ...] = (
    "paper:prop-1", "paper:prop-2",
    "thesis:thm-1.3.2", "thesis:prop-1.3.3", "thesis:prop-1.4.1", "thesis:prop-1.4.2", "thesis:prop-1.4.3",
    "thesis:prop-1.5.1", "thesis:prop-1.5.2", "thesis:prop-2.3.1", "thesis:prop-2.3.3", "thesis:prop-2.4.2",
    "thesis:prop-2.5.2", "thesis:prop-2.5.3", "thesis:prop-2.5.4", "thesis:prop-2.5.5", "thesis:thm-4.4.1",
    "thesis:claim-4.4.2-corollary",
    "stumfoll:lemma-1", "stumfoll:lemma-2",
    "aranovskiy:prop-1", "aranovskiy:prop-2", "aranovskiy:prop-3",
)

CLAIMS: tuple[Claim, ...] = (
    Claim("thesis:prop-1.3.3", "§1.3, Proposition 1.3.3",
          "For phi convex, proper and lower semicontinuous and p = Prox_{gamma phi}(x): ||y - p||^2 <= ||x - y||^2 "
          "- 2 gamma (phi(p) - phi(y)) for every y.", "an inequality (no number)",
          test=f"{_MHE}::test_prop_1_3_3_proximity_inequality",
          notes="On the DIP's centred least-squares functional (gamma 150 and 24400) and on ||z||_1; a nonconvex "
                "double well violates it, so the check can fail."),
    Claim("thesis:prop-1.5.1", "§1.5.2, Proposition 1.5.1 (1.27)",
          "The subspace estimator's error obeys e_{k+1} = Phi U_p Lbar_p U_p^T e_k + Phi U_pc U_pc^T e_k + Phi U_p "
          "Lddot_p U_p^T zeta_k - eta_k.", "an identity (no number)",
          test="tests/test_theory_mhe.py::test_prop_1_4_2_cpx_and_1_5_1_scpx",
          notes="The SCPX branch (p = 2 of 3) of that test: recursion and simulated estimator agree to 1e-10."),
    Claim("thesis:prop-2.3.1", "§2.3.1, Proposition 2.3.1",
          "The projection control (2.9) moves f(x_k) to its P-norm projection onto {y : g(x_k)^T P y = 0}.",
          "a proposition (no number)", test=f"{_PROJ}::test_prop_2_3_1_projection",
          notes="§2.7.2 example and the DIP (ZOH, 1 ms); reference: SciPy null space in the Cholesky metric."),
    Claim("thesis:prop-2.3.3", "§2.3.2, Proposition 2.3.3",
          "If P is globally exponentially stabilising for (2.9) with constant alpha (Def. 2.3.2) and every gamma_k "
          "exceeds (1 - sqrt(alpha))/sqrt(alpha), the relaxed projection control (2.10) is globally exponentially "
          "stable (decrease factor alpha - 1/(gamma_min + 1)^2).", "a proposition (no number)",
          test=f"{_PROJ}::test_prop_2_3_3_linear_example; ::test_prop_2_3_3_nonlinear_example; "
               "::test_prop_2_3_3_hypothesis_fails_on_the_dip_p",
          notes="§2.7.1: alpha = 0.78, the decrease holds for all x (generalised eigenvalues); §2.7.2 on a grid. "
                "The DIP's P (spectral radius 0.999 under (2.9)) has alpha < 0: the proposition does not apply "
                "there."),
    Claim("thesis:prop-2.5.2", "§2.5, Proposition 2.5.2 (2.17)",
          "Closed form of the state under the linear relaxed projection control (2.16).", "a formula (no number)",
          test=f"{_PROJ}::test_prop_2_5_2_closed_form",
          notes="Derived again: the first term is T^k x_0, not the printed T^k v_0 (the printed form drops "
                "T^k z_0, which the test shows is far above rounding). The corrected form matches (2.16) "
                "simulated on §2.7.1 and the DIP."),
    Claim("thesis:prop-2.5.3", "§2.5, Proposition 2.5.3",
          "With P stabilising (Def. 2.5.1) and any positive gamma_k, the state stays bounded: ||x_k||^2 <= "
          "M (||v_0||^2 + ||z_0||^2/(1 - sigma)).", "a bound (no number)",
          test=f"{_PROJ}::test_prop_2_5_3_bounded",
          notes="Asserted in the form that follows from the corrected (2.17): ||x_k|| <= M (||x_0|| + "
                "||z_0||/(1 - sigma)); the printed squared form also held on the same trajectories (printed by "
                "the test)."),
    Claim("thesis:prop-2.5.4", "§2.5, Proposition 2.5.4",
          "If 1/(1 + gamma_k) < eta < 1 for all k, the linear relaxed projection control is globally "
          "exponentially stable.", "a proposition (no number)", test=f"{_PROJ}::test_prop_2_5_4_exponential",
          notes="Bound M sigma^k ||x_0|| + M ||z_0|| k r^k, r = max(sigma, eta), on §2.7.1 and the DIP; with "
                "gamma_k = 1/(k+1)^2 (hypothesis broken) Q x_k stalls at pi/sinh(pi) Q x_0."),
    Claim("thesis:prop-2.5.5", "§2.5, Proposition 2.5.5 with (2.18)",
          "With gamma_k = gamma/||x_k||^alpha the linear relaxed projection control is globally exponentially "
          "stable.", "a proposition (no number)", test=f"{_PROJ}::test_prop_2_5_5_state_weights",
          notes="§2.7.1 with the thesis's gamma 0.45, alpha 3 from [2, 1]; the DIP with gamma 1, alpha 2: the "
                "weights stay under the eta the proof derives from Prop. 2.5.3, and the state decays."),
    Claim("stumfoll:lemma-1", "§3.2 (system (30)), Lemma 1 (cited from Sadegh)",
          "If the state-transition matrix of x_{k+1} = F(k) x_k has norm at most 1 for all k_1, k_0, the system "
          "is stable.", "a lemma (no number)", test=f"{_DMSO}::test_lemmas_1_2_weight_recursion",
          notes="Checked on the DMSO weight recursion with the thesis's tanh basis: no psi(k_1, 0) exceeds 1."),
    Claim("stumfoll:lemma-2", "§3.2, Lemma 2 and Definition 1 (persistent excitation)",
          "For F(k) = I - Gamma phi_k phi_k^T with 0 < Gamma < 2 and sum over a window of phi phi^T > 0, the "
          "state-transition matrix over a window has norm < 1.", "a lemma (no number)",
          test=f"{_DMSO}::test_lemmas_1_2_weight_recursion",
          notes="Holds with 0 < Gamma ||phi_k||^2 < 2; the printed 0 < Gamma < 2 suffices only for ||phi|| <= 1, "
                "and the thesis's basis [1, tanh(x)] has ||phi||^2 in [1, 5]: Gamma = 1.9 on saturated states "
                "makes psi grow (shown by the test)."),
    Claim("aranovskiy:prop-3", "§V-B, Proposition 3 (observer (24), error dynamics (25), LMIs (27))",
          "With the LMIs (27) feasible there are eps_alpha > 0 and a compact set Omega_alpha such that for "
          "alpha_p in (1 - eps_alpha, 1] and s(0) in Omega_alpha, s -> 0 and zhat -> z.",
          "a proposition (no number)",
          test=f"{_RWP}::test_prop_3_linearisation_eigenvalues; ::test_prop_3_lyapunov_along_trajectories; "
               "::test_prop_3_fails_without_its_hypothesis; ::test_prop_3_closed_loop_on_the_plant",
          notes="Paper's parameters (L 0.01, k_p 5 and 12, alpha_p 0.9; c0 = 0.9 ours). A0 is Hurwitz for "
                "cos z1 in [0.9, 1] (Routh limit L < 5/(12 + a1 c) = 0.081); V from the Lyapunov equation "
                "decreases along (25) at alpha_p = 1 but rises at alpha_p = 0.9; the LMI (27) V decreases there "
                "and s -> 0 from inside Omega; L = 0.1 diverges. On the plant (2)-(3) in closed loop (d = -0.08) "
                "d-hat tends to tan(d), not d: the residual d^3/3 = 1.7e-4 is the approximation behind (20)."),
)

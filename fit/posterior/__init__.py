"""A posterior of what the paper's data leave uncertain in the fitted surrogate and its rig
(issue #24; DESIGN.md section 3.6).

    python -m fit.posterior            # the posterior -> surrogates/<name>-posterior.npz/.json
    python -m fit.posterior --nuts     # NUTS on the EF block against its Laplace
    python -m fit.posterior --importance  # importance sampling of the mechanics+bench block
    python -m fit.posterior --smc      # tempered SMC of the mechanics+bench block
    python -m fit.posterior --check    # Table II and the 30-bpm bench against their bands
    python -m fit.posterior --sbc      # simulation-based calibration of the EF block
    python -m fit.posterior --sbc --block mechanics+bench  # ... of the rest's Laplace
    python -m fit.posterior --sobol    # Sobol indices (SALib) against the linear shares

- :mod:`fit.posterior.blocks`: the parameters (the fit's raw coordinates) and each block's
  whitened residuals, sigmas and priors;
- :mod:`fit.posterior.laplace`: the discrepancy's size from leave-one-out residuals and the cut
  posterior's Gauss-Newton Laplace approximation;
- :mod:`fit.posterior.artifact`: computing it from the shipped fit and writing the draws;
- :mod:`fit.posterior.nuts`: NUTS on the EF block (NumPyro, forward mode; ArviZ diagnostics):
  its shipped draws and the check of its Laplace;
- :mod:`fit.posterior.importance`: the mechanics+bench block's Laplace by importance sampling;
- :mod:`fit.posterior.smc`: tempered SMC of the mechanics+bench block: its shipped draws and
  the check of its Laplace;
- :mod:`fit.posterior.check`: the held-out checks (Table II, the 30-bpm bench, one afterload
  left out at a time);
- :mod:`fit.posterior.sbc`: simulation-based calibration of the EF block, and of the
  mechanics+bench block's Laplace at a linearised refit;
- :mod:`fit.posterior.sobol`: Sobol indices against the linear variance shares of the draws.

The draws are carried through the solve by :func:`cardiosoft.pump.load_posterior` and
:mod:`cardiosoft.posterior`; :mod:`cardiosoft.explain` says what dominates a band.
"""

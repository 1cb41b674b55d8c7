"""Real success predicted from simulation plus a few real trials: prediction-powered inference (`bench predict`).

- `tables`: the real (and tabled sim) outcome files, a sim run's records, and the strata (policy, cell,
  condition) that pair them, with the checks that real and sim describe the same policy and conditions.
- `ppi`: the estimator (PPI++, Angelopoulos et al. 2023), its interval as an effective number of trials,
  the real-only Wilson interval beside it, and the real trials needed for a target width.
"""

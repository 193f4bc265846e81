"""Where model and measurement disagree: the discrepancy loop (``engine``), its model plug-ins (``models``), the
candidates' screen (``screening``), result types (``result``) and the report (``report``).

Kept import-light: the command line reads the defaults below without loading CasADi."""

#: evaluation budget of one candidate's fit: simulations of the training part (whole logs; shorter windows count
#: their share; a size probe's simulation of a costlier model counts more, ``identify.EvaluationBudget``). A refit
#: from the screen's step converges in 40-300 (measured: hardening 43-68, Stribeck 150-290 on 7 s training parts at
#: 5 kHz); the budget is a count, so the answer is the same on any machine.
DEFAULT_BUDGET = 300.0

#: practical significance: a named effect must remove more than 1 % of what the model leaves in the held-back data
#: (a ratio of two costs: the noise level's scale cancels in it)
MIN_GAIN = 1.01

#: a model whose sensor residual stays above its level times the sensor's noise (on the training or the held-back
#: part) does not explain its log: effects it names are tentative, and where the residual sits is reported as
#: unexplained. The level is the one a model that reproduces its log (its residual the sensor's white noise) exceeds
#: by chance with probability ``CONFIDENT_ALPHA`` on either part (``ident.fitting.noise.at_noise_level``: the
#: residual RMS's own scatter and the noise estimate's), and never above ``CONFIDENT_OVER_NOISE``: 1.024x on the
#: training part of a 10 s log at 5 kHz, 1.028x held back. Measured on the independent generator's logs (drives
#: 5102/5103, default design): models with the right effect end at 0.994-1.000x (0.97-1.004x read against the
#: identifier's noise estimate alone, before ``noise_load_rad``). A fixed 1.05x is 6 standard deviations of that
#: scatter at 35,000 samples: a new drive's model with a wrong name ended at 1.041x, some 2,900 noise variances above
#: the truth's cost, and was named confidently.
CONFIDENT_OVER_NOISE = 1.05
#: the chance that a model reproducing its log is above its level on a part (the level is at most
#: ``CONFIDENT_OVER_NOISE``)
CONFIDENT_ALPHA = 1e-3


def above_level(over: tuple[float, float] | None, levels: tuple[float, float]) -> bool:
    """The first reason a name is tentative: the model's residual over the sensor noise (training, held back;
    ``ModelPlugin.over_noise``) is above its level (``ModelPlugin.confident_levels``) on either part, so it does not
    reproduce its log. False when the noise is not known (``over`` None). The one place the level is applied."""
    return over is not None and any(o > lv for o, lv in zip(over, levels))


def levels_text(levels: tuple[float, float]) -> str:
    """The two levels as the report prints them."""
    return f"{levels[0]:.4g}x / {levels[1]:.4g}x (training / held back)"

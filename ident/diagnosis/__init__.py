"""Where model and measurement disagree: the discrepancy loop (``engine``), its model plug-ins (``models``), the
candidates' screen (``screening``), result types (``result``) and the report (``report``).

Kept import-light: the command line reads the defaults below without loading CasADi."""

#: evaluation budget of one candidate's fit: simulations of the training part (whole logs; shorter windows count
#: their share). A refit from the screen's step converges in 40-300 (measured: hardening 43-68, Stribeck 150-290
#: on 7 s training parts at 5 kHz); the budget is a count, so the answer is the same on any machine.
DEFAULT_BUDGET = 300.0

#: a model whose sensor residual stays above this many times the sensor's noise (on the training or the held-back
#: part) does not explain its log: effects it names are tentative, and where the residual sits is reported as
#: unexplained. A model that explains its log ends at 0.98-1.02x (the noise estimate, the identifier's white part of
#: the base fit's residual, is itself accurate to a few %); 1.05 leaves room for that.
CONFIDENT_OVER_NOISE = 1.05

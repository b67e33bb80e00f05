"""Finished runs' elites scored again, between the runner (which trained them) and the results
(which draw and tabulate what this measures); only `results` and the CLI use it.

Modules, one concept each: `lanes` (where each elite goes in a batch to be scored again: its
own lane, on which bit-for-bit replay depends), `replay` (elites rolled out again by the
program that scored them, for drawing their gaits), `perturbations` (what `smol-dsl
robustness` perturbs and what it refuses before measuring), `robustness` (the measuring:
every final archive re-scored under each perturbation's samples, and the corrected archive).
Importing this package or its modules imports no JAX; measuring and replaying do.
"""

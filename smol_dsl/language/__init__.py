"""The `.sched` schedule language: text -> syntax tree -> exact sympy -> proof -> JAX."""

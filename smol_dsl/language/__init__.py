"""The `.sched` schedule language: text -> syntax tree -> exact sympy -> proof -> JAX.

The public API is re-exported by `smol_dsl` (`load`, `parse`, `Schedule`, `Certificate`,
`library_names`). The modules, in the order a schedule goes through them:

- `sched.lark`: the grammar, one rule per segment shape (`KEYWORD_shape`).
- `grammar`: sched.lark completed from the shape registry; the reserved words.
- `syntax`: text -> syntax tree (the Lark parser, its Transformer, friendly syntax errors).
- `tree`: the syntax tree's node types.
- `compiler`: syntax tree -> exact sympy: constants, positions, each segment through its shape.
- `symbolic`: the exact form: the variable `T`, pieces, segments, programs.
- `shapes`: the shape registry, one unit per kind of segment (`shapes.base.Shape`).
- `verify`: the language's rules proven, and the `Certificate`.
- `prover`: extrema, monotonicity and domains of a function of t, by sympy or interval arithmetic,
  under CPU-time budgets.
- `float32`: proof that the float32 program of a formula is finite and close to exact.
- `jaxify`: a formula's sympy expression -> a JAX function.
- `schedule`: `Schedule`, `parse` and `load`: evaluating alpha in JAX.
- `library`: where the bundled schedules live.
"""

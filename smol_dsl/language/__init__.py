"""The `.sched` schedule language: text -> syntax tree -> exact sympy -> proof -> JAX.

A file schedules one or more channels (physical parameters of the body: `gear`, the paper's
alpha, `mass`, `friction`, `gravity`, or some actuators' or links' only), each proven and
evaluated on its own. The public API is re-exported by `smol_dsl` (`load`, `parse`,
`Schedule`, `Curve`, `Certificate`, `Channel`, `GEAR`, `library_names`). The
modules, in the order a schedule goes through them:

- `channels`: the channel kinds and `Channel` (a kind, and the actuators or links it is limited to).
- `sched.lark`: the grammar, one rule per segment shape (`KEYWORD_shape`).
- `grammar`: sched.lark completed from the shape registry; the reserved words.
- `text`: the checks of a text before it is parsed (size, control characters, not empty).
- `syntax`: text -> statements (the Lark parse and its Transformer).
- `hints`: parse errors in words, located and with a hint.
- `assembly`: statements -> program (channel lines checked, directives, lets, sections); `parse_program`.
- `tree`: the syntax tree's node types: the statements and the assembled program.
- `expressions`: a syntax-tree expression -> exact sympy, under a `Scope` of names.
- `compiler`: program -> exact sympy: constants, each channel's section, each segment through its shape.
- `symbolic`: the exact form: the variable `T`, pieces, segments, each channel's curve, programs.
- `shapes`: the shape registry, one unit per kind of segment (`shapes.base.Shape`), and the
  `SegmentContext` a unit compiles its segment with.
- `verify`: the language's rules proven for each channel, step by step.
- `segment_rules`: steps 6 to 9 of verification: each segment's proven range against the rules
  and its declarations.
- `certificates`: what verification proves, as data: `Certificate` and its pieces and joins.
- `prover`: extrema, monotonicity and domains of a function of t, by sympy or interval arithmetic,
  under CPU-time budgets.
- `float32`: proof that the float32 program of a formula is finite and close to exact.
- `jaxify`: a formula's sympy expression -> a JAX function.
- `curve`: `Curve`: one channel evaluated in JAX.
- `schedule`: `Schedule`, `parse` and `load`: a file's channels, alpha and all of them in JAX.
- `library`: where the bundled schedules live.
"""

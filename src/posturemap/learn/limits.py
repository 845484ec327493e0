"""The training parameters' bounds, without numpy (the command line checks its options with
them before anything heavy is imported; :class:`~posturemap.learn.upm.UniformPostureMap`
checks the radius, neighbourhood and epochs alike, and any seed that is a whole number, not
negative: ``MAX_SEED`` bounds the command line's ``--seed``, which ``posturemap bench`` gives numpy's
legacy generator).

Past them a map is meaningless or cannot be computed: a radius whose square overflows (or an
infinite one, which resolves nothing and cannot be written into a map file's JSON), more graph
hops than any map has neurons, a training that would not end, a seed numpy's legacy generator
(seeded by ``posturemap bench``) refuses.
"""

MAX_RADIUS = 1e6
MAX_NEIGHBORHOOD = 1_000_000
MAX_EPOCHS = 10_000
MAX_SEED = 2**32 - 1

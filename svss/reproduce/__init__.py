"""``svss reproduce``: the seed paper's simulation results, reproduced end to end.

Modules: :mod:`.scenes` (the seed's scenes and their variants, the two arrays, the pings
a measure needs), :mod:`.image` (imaging a region with the exact sediment speed),
:mod:`.measures` (pure functions: the multipath features of a depth profile, a target's
excess over the median background), :mod:`.figures` (PNG figures), :mod:`.report` (the
markdown report) and :mod:`.run` (the command). See docs/reproduce.md.
"""

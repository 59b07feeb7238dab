"""The decomposition proper: convex hull geometry (:mod:`.hull`), the concavity that stops the
recursion (:mod:`.concavity`), the recursive split tree and its merge pass (:mod:`.tree`), and
engine limits on each hull (:mod:`.limits`).

(Named ``decomposition``, not ``decompose``: ``pointcvx.decompose`` is the entry function.)
"""

"""``make test-robust``: the accuracy tests on perturbed inputs and several seeds.

A package, so that its modules (``robust.test_visual``, ``robust.conftest``) never take the
names of the main suite's modules of the same file name.
"""

"""``assert_same_steps``: two recorded runs of an env (lists of step or reset tuples) are equal bit
for bit, info dicts included (the snapshot, copy and pickle tests compare runs this way)."""

import numpy as np


def assert_same_steps(expected, actual):
    assert len(expected) == len(actual)
    for a, b in zip(expected, actual):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            if isinstance(x, dict):
                assert x.keys() == y.keys()
                for key in x:
                    np.testing.assert_array_equal(np.asarray(x[key], dtype=object if x[key] is None else None),
                                                  np.asarray(y[key], dtype=object if y[key] is None else None),
                                                  err_msg=key)
            else:
                np.testing.assert_array_equal(x, y)

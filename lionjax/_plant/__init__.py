"""The device twin (GUIDE §6): piecewise base model, effects, simulation of records.

The public names live in :mod:`lionjax.twin`."""

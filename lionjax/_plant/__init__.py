"""The device twin: piecewise base model, effects, simulation of records (docs/method.md,
"Effects").

The public names live in :mod:`lionjax.twin`."""

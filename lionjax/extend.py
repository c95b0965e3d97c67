"""Building blocks for extending lionjax: ``lionjax.extend``.

The abstract bases a new piece subclasses (each documents the methods it must implement), and
the lower-level functions the core is built from:

- :class:`AbstractOutput`: a quantity :func:`lionjax.lion_batched` accumulates while it runs
  (``init`` / ``update`` / ``finalise``), like :class:`lionjax.LSStatistics`;
- :class:`AbstractSampleStepper`: a θ update over one sample interval, like
  :class:`lionjax.ExactStep`;
- :class:`AbstractBatchMethod`: a method of :func:`lionjax.identify_batch`;
- :class:`lionjax.diagnosis.AbstractCandidate`: an effect the diagnosis can name;
- :class:`Column`, :class:`Regressors`: the filtered regressor columns a model or effect builds;
- :func:`equation_error`: ε(t) of a model for a fixed θ; :func:`gram_lstsq`: least squares
  from the statistics ΦᵀΦ, Φᵀy, yᵀy a streamed accumulator keeps;
- :func:`phi_sym2`: E(Z) = (I − e^{−Z})Z⁻¹ of Lion's exact step, elementwise;
- :func:`zero_phase_velocity`, :func:`dahl_states`: the velocity and Dahl's friction state
  that friction effects build their columns from;
- :func:`parse_columns`: the column spec of text records; :func:`host_devices`: how many host
  devices the batched estimators can shard over.
"""

from ._batched import host_devices as host_devices
from ._estimators import AbstractSampleStepper as AbstractSampleStepper
from ._identify_many import AbstractBatchMethod as AbstractBatchMethod
from ._io import parse_columns as parse_columns
from ._least_squares import equation_error as equation_error, gram_lstsq as gram_lstsq
from ._model_effects import (
    dahl_states as dahl_states,
    zero_phase_velocity as zero_phase_velocity,
)
from ._models import Column as Column, Regressors as Regressors
from ._outputs import AbstractOutput as AbstractOutput
from ._phi import phi_sym2 as phi_sym2

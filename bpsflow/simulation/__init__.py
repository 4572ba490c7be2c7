"""The simulation layer: one way every command runs a model.

- :mod:`bpsflow.simulation.idf` reads and assembles the model (IDF text, no IDD);
- :mod:`bpsflow.simulation.backend` is the backend protocol and ``choose_backend``;
- :mod:`bpsflow.simulation.ensemble` is the one ensemble loop (manifest, resume,
  lock, failure isolation, progress) over a replaceable executor;
- :mod:`bpsflow.simulation.energyplus` and :mod:`bpsflow.simulation.surrogate`
  are the two backends.

Callers import the protocol and the loop, never a concrete backend.
"""

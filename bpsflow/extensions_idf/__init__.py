"""IDF snippets of model extensions (``model.idf_objects``), shipped as package data.

Each ``<name>.idf`` adds objects to the shipped test cell (zone ``Cell``,
schedule ``AlwaysOn``) at a design value of 0, so that the extended model
reproduces the original one until a parameter sets the design value. A
relative ``Schedule:File`` name is read next to the snippet: copy the snippet
into a run directory and write its CSV beside it.
"""

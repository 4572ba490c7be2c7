"""IDF templates of model extensions (``model.idf_objects``), shipped as package data.

Each ``<name>.idf`` adds objects at a design value of 0, so that the extended
model reproduces the original one until a parameter sets the design value.
The files are templates, not IDF: ``{object}``, ``{zone}``, ``{schedule}``
and ``{file}`` stand for the added object's name, the zone it is written
for, its schedule's name and the schedule's CSV file.
:func:`bpsflow.diagnosis.extensions.render_snippet` fills them for a model
(names chosen so that they cannot clash with the model's; a constant
schedule is created by the snippet itself, never assumed to exist) and
:func:`bpsflow.diagnosis.extensions.extend_config` writes the result, with
its CSV beside it, into the diagnosis folder's ``extensions/``. A relative
``Schedule:File`` name is read next to the snippet.
"""

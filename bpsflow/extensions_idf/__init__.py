"""IDF templates of model extensions (``model.idf_objects``), shipped as package data.

Each ``<name>.idf`` adds objects at a design value of 0, so that the extended
model reproduces the original one until a parameter sets the design value
(``thermal_mass.idf`` keeps a token 0.001 m² of InternalMass, which
EnergyPlus needs, and its parameter adds to it).
The files are templates, not IDF: ``{object}``, ``{zone}``, ``{schedule}``,
``{file}``, ``{material}`` and ``{construction}`` stand for the added
object's name, the zone it is written for, its schedule's name, the
schedule's CSV file and the names of a material and construction the
snippet defines. A placeholder is a lower-case word in braces, so a unit
comment must not be one (write ``(m)``, not ``{m}``).
:func:`bpsflow.diagnosis.extensions.render_snippet` fills them for a model
(names chosen so that they cannot clash with the model's; a constant
schedule is created by the snippet itself, never assumed to exist) and
:func:`bpsflow.diagnosis.extensions.extend_config` writes the result, with
its CSV beside it, into the diagnosis folder's ``extensions/``. A relative
``Schedule:File`` name is read next to the snippet.
"""

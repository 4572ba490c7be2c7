"""bpsflow: building performance simulation under uncertainty, from one YAML file.

The command line is :mod:`bpsflow.cli`; the simulation layer every command goes
through is :mod:`bpsflow.simulation`.
"""

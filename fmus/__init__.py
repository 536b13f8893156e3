"""Modelica-to-FMU pipeline: front end, symbolic model, C code generation, FMI runtime, packaging."""

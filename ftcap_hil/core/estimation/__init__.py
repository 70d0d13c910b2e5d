"""Fault estimation: the filters, their decisions, the step and wave models."""

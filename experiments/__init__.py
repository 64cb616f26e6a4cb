"""Experiment configs and the runner that turns a YAML file into results."""

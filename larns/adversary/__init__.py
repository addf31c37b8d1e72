"""Adversaries for testing a ``--secure`` fleet (docs/security.md): the attacks behind `larns attack`."""

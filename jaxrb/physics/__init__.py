"""One step: make_step and rollout, dynamics, integrators, collision, contact, adjoints."""

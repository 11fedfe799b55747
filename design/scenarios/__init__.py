"""Built-in simulation scenarios (package data): the papers' experiments, named after their figures."""

"""Design: drive descriptions, operating points and the automatic linearization of the observers."""

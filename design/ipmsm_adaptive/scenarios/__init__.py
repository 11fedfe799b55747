"""Built-in scenarios of the adaptive-observer family: the experiments of Piippo et al. (2008)."""

"""Built-in scenarios of the reduced-order observer family: the experiments of De Angelo et al. (2006)."""

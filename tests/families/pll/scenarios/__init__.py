"""Built-in scenario TOMLs of the PLL test family."""

"""Reports: pole maps, figures and data files a drive engineer reviews."""

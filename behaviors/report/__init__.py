"""Reading runs back: FCD export, realism measures, the agents table, plots and pictures."""

"""Built-in simulated worlds: YAML data files read by ``drivers.scenario``. No code lives here."""

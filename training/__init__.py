"""Lightning training of the learned matcher: modules, data modules, command entry points."""

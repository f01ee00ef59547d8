"""What the components of the simulated OR share and none of them owns: rigid-body
geometry, the KUKA LWR 4+ model, the procedure file. Components import from here,
never from one another's packages."""

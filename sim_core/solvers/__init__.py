"""Solvers for one world or N: the step contract and ``make_solver``, explicit, implicit and
static steps, their Krylov solves and preconditioners, contact, and the FEM references."""

"""Solvers: prescribed motion, statics, harmonic balance, continuation, time marching."""

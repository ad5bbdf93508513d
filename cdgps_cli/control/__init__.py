"""Control with GPS in the loop (1998 paper, Sec. V): LQR design, thruster allocation and PWPF
modulation.  Numerics only: arrays in, arrays and records out; files are read and written elsewhere."""

"""Kinematics: rotations (``so3``), the product-of-exponentials model (``poe``), its minimal parameterisation
(``parameterisation``) and the numpy/casadi building blocks (``casadi_expr``)."""

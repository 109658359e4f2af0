"""Kinematics: rotations (``so3``), the product-of-exponentials model (``poe``), its minimal parameterisation
(``parameterisation``), the numpy/casadi building blocks (``casadi_expr``) and the array types annotations use
(``arrays``)."""

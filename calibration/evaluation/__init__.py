"""How good a model is: position/orientation errors (``metrics``), ISO 9283 figures (``iso9283``) and the result of
comparing methods (``comparison``)."""

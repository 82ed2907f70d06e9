"""Training side of itnet (torch): the IT-Net network, data, training and evaluation."""

"""A reconstruction method from outside the package: the encoder's own Gaussians, scored as rows of their own."""

from ushape.evaluation.methods import ReconstructionMethod


class Same(ReconstructionMethod):
    name, label = "same", "same codes"

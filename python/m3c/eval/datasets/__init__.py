"""Readers of evaluation datasets that users bring (nothing here ships their data)."""

from m3c.eval.datasets.threedpw import (OPENPOSE18_TO_COCO17, ThreeDPWPerson, ThreeDPWSequence, list_sequences,
                                        read_sequence)

__all__ = ["OPENPOSE18_TO_COCO17", "ThreeDPWPerson", "ThreeDPWSequence", "list_sequences", "read_sequence"]

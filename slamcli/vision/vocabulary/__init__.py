"""A bag-of-words vocabulary over ORB descriptors and a keyframe database for place recognition.

The vocabulary is a DBoW2-style hierarchical k-majority tree: the root's descriptors are split
into ``branching`` clusters (k-means++ seeding, then a fixed number of k-majority iterations with
Hamming distance and bitwise-majority centroids), each cluster again, down to ``levels`` levels.
The leaves are the words. Each word has an idf weight ``log(N_images / n_images_with_word)``,
so a word seen in every training image weighs nothing.

Node ids number the tree breadth first (0 is the root), and word ids number the leaves in the
same order, so a trained tree depends only on its input and seed: the saved file is
byte-identical for the same input and seed.

A node that holds ``branching`` descriptors or fewer is not clustered: as in DBoW2, each of its
distinct descriptors becomes a leaf child, so such a subtree ends above ``levels`` and leaves can
sit at different depths.

:class:`KeyframeDatabase` is the inverted index (word -> keyframes) that loop closure and
relocalisation query, with ORB-SLAM's candidate filter (keyframes sharing at least 0.8 x the
largest number of common words).

One module per job: :mod:`~slamcli.vision.vocabulary.tree` (the tree, words and vectors),
:mod:`~slamcli.vision.vocabulary.training` (clustering: :func:`train_vocabulary`),
:mod:`~slamcli.vision.vocabulary.files` (:func:`save_vocabulary`, :func:`load_vocabulary`,
:func:`default_vocabulary`),
:mod:`~slamcli.vision.vocabulary.database` (the keyframe database) and
:mod:`~slamcli.vision.vocabulary.training_data` (descriptors of training images).
"""

from __future__ import annotations

from slamcli.vision.vocabulary.database import KeyframeDatabase
from slamcli.vision.vocabulary.files import (
    default_vocabulary,
    default_vocabulary_path,
    load_vocabulary,
    save_vocabulary,
)
from slamcli.vision.vocabulary.training import train_vocabulary
from slamcli.vision.vocabulary.training_data import (
    IMAGE_SUFFIXES,
    INPUT_KINDS,
    TrainingImages,
    extract_training_descriptors,
)
from slamcli.vision.vocabulary.tree import (
    DEFAULT_ITERATIONS,
    DESCRIPTOR_BYTES,
    FORMAT_TAG,
    FORMAT_VERSION,
    MAX_NODES,
    TRAIN_HINT,
    BowVector,
    Vocabulary,
    check_descriptors,
    hamming,
)

__all__ = [
    "DEFAULT_ITERATIONS",
    "DESCRIPTOR_BYTES",
    "FORMAT_TAG",
    "FORMAT_VERSION",
    "IMAGE_SUFFIXES",
    "INPUT_KINDS",
    "MAX_NODES",
    "TRAIN_HINT",
    "BowVector",
    "KeyframeDatabase",
    "TrainingImages",
    "Vocabulary",
    "check_descriptors",
    "default_vocabulary",
    "default_vocabulary_path",
    "extract_training_descriptors",
    "hamming",
    "load_vocabulary",
    "save_vocabulary",
    "train_vocabulary",
]

"""Place recognition by appearance: a bag-of-words vocabulary over ORB descriptors and a
keyframe database searched with it (the DBoW2 design).

    from eurocslam.places import KeyframeDatabase, default_vocabulary

    voc = default_vocabulary()                 # shipped with the package, loaded once
    words = voc.lookup(desc)                   # word id per descriptor (n, 32) uint8
    bow = voc.bow(words)                       # TF-IDF, L1-normalised BowVector
    db = KeyframeDatabase()
    best = db.query(bow, 5, exclude_last=20)   # [Candidate(key, score)], best first
    db.add(key, bow)

The database only proposes candidates; loops and relocalizations need geometric verification.
How the shipped vocabulary was built and how to rebuild it: docs/architecture.md, "Place
recognition"; `python -m eurocslam.places.train --help`.
"""

from eurocslam.places.database import Candidate, KeyframeDatabase
from eurocslam.places.vocabulary import BowVector, Vocabulary, default_vocabulary

__all__ = [
    "BowVector",
    "Candidate",
    "KeyframeDatabase",
    "Vocabulary",
    "default_vocabulary",
]

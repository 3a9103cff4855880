import numpy as np

from vprsnn_export.config import Config
from vprsnn_export.network.modules import ensemble_neurons, module_count, module_regions, neuron_modules, region_mask


def test_regions_cut_the_places_into_consecutive_runs_the_last_one_shorter():
    assert module_count(2400, 100) == 24 and module_count(250, 100) == 3 and module_count(250, 0) == 1
    assert module_regions(250, 100).tolist() == [[0, 100], [100, 200], [200, 250]]
    assert module_regions(250, 0).tolist() == [[0, 250]]
    assert ensemble_neurons(Config().replace(**{"train.module_size": 100}), 250) == 1200


def test_region_mask_marks_each_neurons_own_places():
    regions = module_regions(5, 2)
    mask = region_mask(regions, 2)
    assert mask.shape == (6, 5)
    assert mask[neuron_modules(6, 2) == 2].tolist() == [[False, False, False, False, True]] * 2
    assert np.array_equal(mask.sum(axis=1), [2, 2, 2, 2, 1, 1])

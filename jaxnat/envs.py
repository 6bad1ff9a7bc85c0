"""The registered env ids. Entry points are strings, so nothing heavy is imported here."""

from jaxnat.registration import register

_CLASSIFY = "jaxnat.vision_envs.classify:Classify"
for _name, _dataset in [
    ("MNIST", "mnist"),
    ("FashionMNIST", "fashion_mnist"),
    ("Digits", "digits"),
    ("CIFAR10", "cifar10"),
    ("CIFAR100", "cifar100"),
    ("ImageFolder", "image_folder"),
]:
    register(f"Classify/{_name}-v0", _CLASSIFY, dataset=_dataset)

_LOCALIZE = "jaxnat.vision_envs.localize:Localize"
register("Localize/Cityscapes-v0", _LOCALIZE, dataset="cityscapes")
register("Localize/Clutter-v0", _LOCALIZE, dataset="clutter")

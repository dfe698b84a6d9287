"""train_localization: along-track localisation of maglev and railway vehicles."""

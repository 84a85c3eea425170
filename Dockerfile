# One image for the portal's processes (web, streams, workers, collector, beat) and the simulated agent.
FROM node:20-bookworm-slim AS assets
WORKDIR /src
COPY package.json package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error

FROM python:3.11-slim-bookworm
ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 AMAZING_VAR_DIR=/var/lib/amazing
WORKDIR /app
COPY pyproject.toml README.md ./
COPY core core
COPY portal portal
COPY bookings bookings
COPY basestation basestation
COPY manage.py ./
RUN pip install --no-cache-dir '.[portal,basestation]'
COPY --from=assets /src/node_modules/@picocss/pico/css/pico.min.css var/assets/vendor/pico/
COPY --from=assets /src/node_modules/chart.js/dist/chart.umd.js var/assets/vendor/chart.js/
COPY --from=assets /src/node_modules/luxon/build/global/luxon.min.js var/assets/vendor/luxon/
COPY --from=assets /src/node_modules/@event-calendar/build/dist/event-calendar.min.js /src/node_modules/@event-calendar/build/dist/event-calendar.min.css var/assets/vendor/event-calendar/
COPY --from=assets /src/node_modules/js-yaml/dist/browser/js-yaml.umd.min.js var/assets/vendor/js-yaml/
COPY --from=assets /src/node_modules/swagger-ui-dist/swagger-ui-bundle.js /src/node_modules/swagger-ui-dist/swagger-ui-standalone-preset.js /src/node_modules/swagger-ui-dist/swagger-ui.css /src/node_modules/swagger-ui-dist/favicon-32x32.png var/assets/vendor/swagger-ui-dist/
ENV STATIC_ROOT=/app/static
RUN DJANGO_DEBUG=1 AMAZING_VAR_DIR=/tmp/build python manage.py collectstatic --no-input -v 0 \
    && rm -rf /tmp/build \
    && useradd --system --home /var/lib/amazing amazing && mkdir -p /var/lib/amazing \
    && chown amazing /var/lib/amazing
USER amazing
EXPOSE 8000 8001 8700
CMD ["python", "-m", "portal.serve", "--bind", "0.0.0.0:8000"]
